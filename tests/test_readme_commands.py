"""Every shell command of the README and docs/ runs, from (a mirror of) the repository root,
as written: each parses and names files that exist; the ones that end by themselves run to
exit code 0; the ones that run until stopped reach their listening state, take the frames
their page sends them and stop cleanly on Ctrl-C. The few exceptions are listed below, each
with its reason. Every local link reaches its file and heading; no page cites a document
the reader does not have."""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from cmu import ROOT

from streamkey.cli import build_parser

README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
PROGRAMS = {".venv/bin/streamkey", ".venv/bin/pip", ".venv/bin/pytest", "python3", "bash",
            "mkdir", "echo", "oscdump", "redis-server", "redis-cli", "blender",
            "examples/annotate_session.sh"}
FENCES = ("bash", "sh", "shell", "console")

# Commands a test does not run, each with its reason (keep this short).
RUN_BY_CI = {  # .ci/run runs these itself, verbatim (tests/test_architecture.py checks it)
    "python3 -m venv .venv && .venv/bin/pip install -e . && .venv/bin/streamkey demo":
        "a fresh venv with the core dependencies: .ci/run's own first step",
    "bash .ci/run": "CI itself; a test running it would recurse",
}
NOT_ON_CI = {
    "blender --python examples/blender_markers.py -- keys.json --method saliency":
        "the Blender application and its window; CI has Blender as the bpy module only, "
        "with which tests/test_blender.py runs the same script",
    ".venv/bin/streamkey extract /shared/corpus --engine ray --address ray://head:10001 "
    "-o keys.json": "the reader's own Ray cluster and corpus (the local-Ray form runs)",
    ".venv/bin/streamkey extract /shared/corpus --engine dask --address tcp://scheduler:8786 "
    "-o keys.json": "the reader's own Dask scheduler and corpus (the local-Dask form runs)",
    ".venv/bin/streamkey cluster run --from zmq+tcp://capture-host:5555 --shards 8 "
    "--redis redis://redis-host:6379 --address head-host:6379":
        "the reader's own capture host, Redis and Ray cluster (the local form runs)",
}

# Run with a change that keeps them short or harmless: (what runs, reason).
SUBSTITUTE = {
    ".venv/bin/streamkey bench --offline --online":
        (".venv/bin/streamkey bench --offline --online --quick --frames 2000",
         "the full bench measures for 7 minutes; --quick --frames 2000 runs the same steps "
         "on a 2,000-frame motion and a 24,000-frame stream"),
    '.venv/bin/pip install -e ".[plot]"':
        ('.venv/bin/pip install --dry-run -e ".[plot]"',
         "a real install would re-point the environment the tests run in; --dry-run resolves "
         "the same requirements from the repository root"),
    "oscdump 9001":
        ("stdbuf -oL oscdump 9001",
         "in a terminal oscdump prints each message as it comes; into the test's pipe its "
         "output is block-buffered, and stdbuf keeps it line by line"),
}
# Files the pages name as the reader's own, stood in for by a CMU clip of the same kind.
PLACEHOLDERS = {"take_exported_by_axis.bvh": "../shared/data/cmu/07_05.bvh"}


@dataclass(frozen=True)
class Step:
    """One command of a scenario: `live` ones are started and waited on until they print
    their ready line (stopped with Ctrl-C at the end: exit code 0); `background` ones are
    started and stopped at the end; `watch` ones are started first and must print `until`
    before the end; the rest run to exit code 0, in order."""

    line: str
    role: str = "finite"  # live, background, watch, finite
    until: str = ""
    ready: str = "listening on"


@dataclass(frozen=True)
class Scenario:
    """Commands of one page that work together (a receiver and its sender), and what the
    run must have written."""

    name: str
    steps: tuple[Step, ...]
    files: dict[str, tuple[str, ...]] = field(default_factory=dict)  # file -> texts in it
    said: str = ""  # a line the live command must print (its summary's events, say)
    cluster: bool = False


SCENARIOS = [
    Scenario(
        "README live: run, replay into it, oscdump the events",
        (Step("oscdump 9001", "watch", "/keyframe "),
         Step(".venv/bin/streamkey run --from osc://127.0.0.1:9000 --skeleton "
              "../shared/data/cmu/07_05.bvh --to jsonl:session.jsonl --to osc://127.0.0.1:9001 "
              "--to ws://127.0.0.1:8765", "live"),
         Step(".venv/bin/streamkey replay ../shared/data/cmu/07_05.bvh "
              "--to osc://127.0.0.1:9000")),
        {"session.jsonl": ('"type":"keyframe"',)}),
    Scenario(
        "README recipe: music / dance over OSC, rehearsed with a replay",
        (Step(".venv/bin/streamkey run --from osc://127.0.0.1:9000 --skeleton "
              "../shared/data/cmu/05_06.bvh --to osc://127.0.0.1:9001", "live"),
         Step(".venv/bin/streamkey replay ../shared/data/cmu/05_06.bvh "
              "--to osc://127.0.0.1:9000")),
        said=r"^events: .*saliency [1-9]"),
    Scenario(
        "streams: two replays into one run",
        (Step(".venv/bin/streamkey run --from osc://127.0.0.1:9000 --to jsonl:stage.jsonl "
              "--max-streams 8 --stream-idle 5 --summary stage.json", "live"),
         Step(".venv/bin/streamkey replay ../shared/data/cmu/07_01.bvh --stream left "
              "--to osc://127.0.0.1:9000 &", "background"),
         Step(".venv/bin/streamkey replay ../shared/data/cmu/09_06.bvh --stream right "
              "--to osc://127.0.0.1:9000")),
        {"stage.jsonl": ('"stream":"left"', '"stream":"right"'),
         "stage.json": ('"left"', '"right"')}),
    Scenario(
        "cluster: Redis, a looping replay, cluster run, the events read back from Redis",
        (Step('redis-server --port 6379 --save "" &', "background"),
         Step(".venv/bin/streamkey replay ../shared/data/cmu/07_05.bvh "
              "--to zmq+tcp://127.0.0.1:5555 --stream alice --loop &", "background"),
         Step(".venv/bin/streamkey cluster run --from zmq+tcp://127.0.0.1:5555 --shards 2 "
              "--redis redis://127.0.0.1:6379 --snapshot-every 600", "live",
              ready="shard actor(s) ready on Ray"),
         Step("redis-cli XREAD BLOCK 0 STREAMS streamkey:default:events '$'")),
        cluster=True),
]
IN_SCENARIOS = {step.line for s in SCENARIOS for step in s.steps}
READY = "listening on"
TIMEOUT = 900  # a fresh machine compiles the numba kernels in the first command (minutes)


@dataclass(frozen=True)
class Block:
    """One fenced shell block of a page: its command lines, continuations joined."""

    page: str
    line: int
    commands: tuple[str, ...]


def command_blocks() -> list[Block]:
    """The shell blocks (```bash, sh, shell, console) of the README and docs/, each line
    with its trailing comment, blank lines and comment lines left out."""
    blocks = []
    for page in PAGES:
        text = page.read_text()
        for m in re.finditer(r"^```(\w*)\n(.*?)^```", text, re.S | re.M):
            if m.group(1) not in FENCES:
                continue
            lines = []
            for line in re.sub(r"\\\n\s*", "", m.group(2)).splitlines():
                line = re.sub(r"\s+#\s.*$", "", line).strip()  # a trailing comment
                line = line.removeprefix("$ ")  # a console prompt
                if line and not line.startswith("#"):
                    lines.append(line)
            if lines:
                blocks.append(Block(page.name, text[:m.start()].count("\n") + 1, tuple(lines)))
    return blocks


def readme_commands() -> list[str]:
    """Every command line of the README's and docs' shell blocks, in page order."""
    return [line for block in command_blocks() for line in block.commands]


def _is_live(line: str) -> bool:
    """A command that runs until stopped (a listener, a looping demo, the session script)."""
    words = shlex.split(line)
    if "|" in words or words[-1] == "&":
        return False
    if words[0] == "examples/annotate_session.sh":
        return True
    sub = words[1:3] if words[0] == ".venv/bin/streamkey" else []
    return sub[:1] == ["run"] or sub == ["cluster", "run"] or (
        sub[:1] == ["demo"] and "--seconds" not in words)


def _skipped(line: str) -> bool:
    return line in RUN_BY_CI or line in NOT_ON_CI


def _simple_commands(line: str) -> list[list[str]]:
    """The simple commands of a line, split at `&&`, `|`, `||`, `;`, `&` and `>`."""
    words = shlex.split(line, comments=True)
    out: list[list[str]] = [[]]
    for word in words:
        if word in ("&&", "|", "||", ";", "&", ">"):
            out.append([])
        else:
            out[-1].append(word)
    return [c for c in out if c]


def test_every_readme_command_names_a_real_program_and_parses():
    lines = readme_commands()
    assert len(lines) > 40
    for line in lines:
        commands = _simple_commands(line)
        after_redirect = {i for i, c in enumerate(commands)
                          if i and f"> {c[0]}" in line}  # `... > roles.json`: a file
        for i, words in enumerate(commands):
            if i in after_redirect:
                continue
            assert words[0] in PROGRAMS, f"{words[0]!r} (bare or unknown program): {line}"
            if words[0] == ".venv/bin/streamkey":
                try:
                    build_parser().parse_args(words[1:])
                except SystemExit as exc:
                    pytest.fail(f"does not parse ({exc.code}): {line}")
            for word in words[1:]:
                if word.startswith(("../shared/", "examples/")):
                    assert (ROOT / word).exists(), f"{word} does not exist: {line}"


def test_every_command_runs_in_one_way_and_the_exceptions_are_few():
    lines = set(readme_commands())
    tables = [*RUN_BY_CI, *NOT_ON_CI, *SUBSTITUTE, *IN_SCENARIOS]
    stale = [line for line in tables if line not in lines]
    assert not stale, f"no longer in the README or docs: {stale}"
    assert not (IN_SCENARIOS & (set(RUN_BY_CI) | set(NOT_ON_CI)))
    assert len(NOT_ON_CI) <= 4 and len(RUN_BY_CI) <= 2
    for scenario in SCENARIOS:  # a receiver first, so nothing it is sent is lost
        assert scenario.steps[-1].role == "finite", scenario.name


# ---- running them ----------------------------------------------------------------------


def _named_clips() -> set[str]:
    text = "\n".join(readme_commands())
    return set(re.findall(r"\.\./shared/data/cmu/([\w.]+)", text))


@pytest.fixture()
def mirror(tmp_path: Path) -> Path:
    """A folder laid out like the repository root (its .venv and examples, ../shared beside
    it), where the pages' commands may write their outputs. Its ../shared/data/cmu holds the
    clips the pages name and the corpus' index files, not every clip: a command over the
    folder runs in seconds, not minutes (the short corpus)."""
    root = tmp_path / "repo"
    root.mkdir()
    for name in (".venv", "examples"):
        (root / name).symlink_to(ROOT / name)
    corpus = ROOT.parent / "shared" / "data" / "cmu"
    short = tmp_path / "shared" / "data" / "cmu"
    short.mkdir(parents=True)
    named = _named_clips()
    for path in corpus.iterdir():
        if path.name in named or path.suffix not in (".bvh", ".amc"):
            (short / path.name).symlink_to(path)
    for name, stand_in in PLACEHOLDERS.items():
        (root / name).symlink_to((root / stand_in).resolve())
    (tmp_path / "sessions").mkdir()
    return root


def _env(mirror: Path) -> dict[str, str]:
    """The environment the commands run in: the dashboard's session logs go to the test's
    folder, not the user's."""
    return {**os.environ, "STREAMKEY_SESSIONS": str(mirror.parent / "sessions")}


def _bash(script: str, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["bash", "-eo", "pipefail", "-c", script], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=TIMEOUT)


class Running:
    """A started command whose stdout and stderr lines are collected as they come."""

    def __init__(self, line: str, cwd: Path, env: dict[str, str]) -> None:
        self.line = line
        command = SUBSTITUTE.get(line, (line, ""))[0].removesuffix("&").strip()
        self.proc = subprocess.Popen(["bash", "-c", f"exec {command}"], cwd=cwd, env=env,
                                     stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        self.out: list[str] = []
        self.err: list[str] = []
        self._changed = threading.Condition()
        self._readers = [threading.Thread(target=self._read, args=(stream, sink), daemon=True)
                         for stream, sink in ((self.proc.stdout, self.out),
                                              (self.proc.stderr, self.err))]
        for reader in self._readers:
            reader.start()

    def _read(self, stream: object, sink: list[str]) -> None:
        for line in stream:  # type: ignore[attr-defined]
            with self._changed:
                sink.append(line)
                self._changed.notify_all()
        with self._changed:
            self._changed.notify_all()

    def wait_for(self, text: str, timeout: float = TIMEOUT) -> None:
        """Until a line of stdout or stderr contains `text` (fails if the command ends or
        the timeout passes first)."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while not any(text in line for line in self.out + self.err):
                assert self.proc.poll() is None, f"ended ({self.proc.returncode}) before " \
                    f"{text!r}: {self.line}\n{''.join(self.err)[-2000:]}"
                left = deadline - time.monotonic()
                assert left > 0, f"no {text!r} within {timeout} s: {self.line}"
                self._changed.wait(min(left, 1.0))

    def stop(self, sig: int = signal.SIGINT) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise
        finally:
            for reader in self._readers:
                reader.join(timeout=10)
            for stream in (self.proc.stdout, self.proc.stderr):
                if stream is not None:
                    stream.close()


def _run_finite(line: str, cwd: Path, env: dict[str, str]) -> None:
    run, _reason = SUBSTITUTE.get(line, (line, ""))
    where = ROOT if run.startswith(".venv/bin/pip") else cwd
    done = _bash(run, where, env)
    assert done.returncode == 0, f"{line}\n{done.stderr[-3000:]}"
    assert "Traceback" not in done.stderr, done.stderr[-3000:]


def _finite_blocks() -> list[object]:
    """Each shell block's commands that end by themselves, to run in order (a later one may
    read what an earlier one wrote)."""
    params = []
    for block in command_blocks():
        lines = [c for c in block.commands
                 if not (_skipped(c) or c in IN_SCENARIOS or _is_live(c))]
        if lines:
            cluster = any("--engine" in c for c in lines)
            marks = [pytest.mark.slow, *([pytest.mark.cluster] if cluster else [])]
            params.append(pytest.param(lines, id=f"{block.page}:{block.line}", marks=marks))
    return params


def _live_lines() -> list[str]:
    return sorted({c for c in readme_commands()
                   if _is_live(c) and not _skipped(c) and c not in IN_SCENARIOS})


@pytest.mark.parametrize("lines", _finite_blocks())
def test_commands_that_end_by_themselves_run_as_written(lines, mirror):
    for line in lines:
        _run_finite(line, mirror, _env(mirror))


@pytest.mark.slow
@pytest.mark.parametrize("line", _live_lines(), ids=lambda c: " ".join(c.split()[1:5]))
def test_commands_that_run_until_stopped_listen_and_stop_cleanly_on_ctrl_c(line, mirror):
    """A listener with nothing to listen to on CI (VMC, Axis Neuron, an OSC rig) passes once
    it is listening, and must then end on Ctrl-C with its summary and exit code 0."""
    command = Running(line, mirror, _env(mirror))
    try:
        command.wait_for(READY)
    finally:
        code = command.stop()
    assert code == 0, "".join(command.err)[-3000:]
    assert any(line.startswith("frames in:") for line in command.err), command.err[-5:]
    assert "Traceback" not in "".join(command.err)


@pytest.mark.slow
@pytest.mark.parametrize(
    "scenario", [pytest.param(s, id=s.name.split(":")[0],
                              marks=[pytest.mark.cluster] if s.cluster else [])
                 for s in SCENARIOS])
def test_commands_that_work_together_run_together(scenario: Scenario, mirror):
    env = _env(mirror)
    started: list[tuple[Step, Running]] = []
    try:
        for step in scenario.steps:
            assert step.line in readme_commands(), step.line
            if step.role == "finite":
                _run_finite(step.line, mirror, env)
                continue
            running = Running(step.line, mirror, env)
            started.append((step, running))
            if step.role == "live":
                running.wait_for(step.ready)
        for step, running in started:
            if step.role == "watch":
                running.wait_for(step.until, timeout=60)
    finally:
        codes = {step.line: (step, running, running.stop()) for step, running in
                 reversed(started)}
    for step, running, code in codes.values():
        if step.role == "live":
            assert code == 0, f"{step.line}\n{''.join(running.err)[-3000:]}"
            assert "Traceback" not in "".join(running.err)
            if scenario.said:
                assert re.search(scenario.said, "".join(running.err), re.M), running.err[-8:]
    for name, texts in scenario.files.items():
        written = (mirror / name).read_text()
        assert all(text in written for text in texts), (name, texts)


# ---- the pages themselves --------------------------------------------------------------


def test_readme_and_docs_cite_no_document_a_reader_does_not_have():
    for path in PAGES:
        text = path.read_text()
        for pattern in (r"\bDESIGN\b", r"\bissues? #?\d", r"\bthe issue\b",
                        r"\.\./shared/(?!data)"):
            assert not re.search(pattern, text, re.I), f"{path.name}: {pattern}"


def _anchors(text: str) -> set[str]:
    """GitHub's heading anchors of a Markdown text."""
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-")
            for h in re.findall(r"^#+ (.+)$", text, re.M)}


def test_every_local_link_of_the_readme_and_docs_reaches_a_file_and_heading():
    for page in PAGES:
        text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            assert dest.exists(), f"{page.name}: {target}"
            if anchor and dest.suffix == ".md":
                assert anchor in _anchors(dest.read_text()), f"{page.name}: {target}"
