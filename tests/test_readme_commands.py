"""The shell commands of the README and docs/, as written: each parses, names files that
exist, and the cheap ones run from (a mirror of) the repository root and succeed; every local
link reaches its file and heading; no page cites a document the reader does not have."""

from __future__ import annotations

import re
import shlex
import subprocess
from pathlib import Path

import pytest
from cmu import ROOT

from streamkey.cli import build_parser

README = ROOT / "README.md"
PROGRAMS = {".venv/bin/streamkey", ".venv/bin/pip", ".venv/bin/pytest", "python3", "bash",
            "mkdir", "echo", "oscdump", "redis-server", "redis-cli", "blender",
            "examples/annotate_session.sh"}

# Run as written (exact README lines; a trailing `\` line joined with the next).
CHEAP = [
    ".venv/bin/streamkey extract ../shared/data/cmu/07_01.bvh --method simplify,optimal "
    "--tolerance simplify=0.05,optimal=0.002",
    ".venv/bin/streamkey extract ../shared/data/cmu/07_01.bvh --method optimal --count 16",
    ".venv/bin/streamkey extract ../shared/data/cmu/05_02.bvh --method saliency --max-gap 1",
    ".venv/bin/streamkey replay ../shared/data/cmu/07_05.bvh --to - | "
    ".venv/bin/streamkey run --from - --to -",
    ".venv/bin/streamkey extract ../shared/data/cmu/07_01.bvh --method saliency -o keys.json "
    "--export-bvh keys.bvh --export-reconstructed rebuilt.bvh",
    ".venv/bin/streamkey sheet ../shared/data/cmu/07_01.bvh --method saliency -o sheet.png",
    ".venv/bin/streamkey plot ../shared/data/cmu/07_01.bvh --method all -o plot.png",
]
# Run together, in order (the second reads what the first wrote).
CHEAP_BLOCKS = [
    ["echo '{\"pelvis\": \"Hips\", \"left_ankle\": \"LeftFoot\", \"right_ankle\": \"RightFoot\"}'"
     " > roles.json",
     ".venv/bin/streamkey extract ../shared/data/cmu/07_01.bvh --method all --roles roles.json"],
]


PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]


def readme_commands() -> list[str]:
    """Every command line of the ```bash blocks of the README and docs/ (continuations
    joined, comments and blank lines left out); all run from the repository root."""
    lines = []
    text = "\n".join(page.read_text() for page in PAGES)
    for block in re.findall(r"```bash\n(.*?)```", text, re.S):
        for line in re.sub(r"\\\n\s*", "", block).splitlines():
            line = re.sub(r"\s+#\s.*$", "", line).strip()  # a trailing comment
            if line and not line.startswith("#"):
                lines.append(line)
    return lines


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


@pytest.fixture()
def mirror(tmp_path: Path) -> Path:
    """A folder laid out like the repository root (its .venv and examples, ../shared beside
    it), where the README's commands may write their outputs."""
    root = tmp_path / "repo"
    root.mkdir()
    for name in (".venv", "examples"):
        (root / name).symlink_to(ROOT / name)
    (tmp_path / "shared").symlink_to(ROOT.parent / "shared")
    return root


def _bash(script: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["bash", "-eo", "pipefail", "-c", script], cwd=cwd,
                          capture_output=True, text=True, timeout=900)


@pytest.mark.slow
@pytest.mark.parametrize("line", CHEAP, ids=lambda c: " ".join(c.split()[1:3]))
def test_cheap_readme_commands_run_as_written(line, mirror):
    assert line in readme_commands(), "the README no longer has this command"
    done = _bash(line, mirror)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Traceback" not in done.stderr


@pytest.mark.slow
def test_readme_command_blocks_run_in_order(mirror):
    lines = readme_commands()
    for block in CHEAP_BLOCKS:
        assert all(line in lines for line in block), block
        done = _bash("\n".join(block), mirror)
        assert done.returncode == 0, done.stderr[-2000:]


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
