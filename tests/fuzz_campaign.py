"""The file fuzz campaign, not run by CI: many mutated files through six commands.

    .venv/bin/python tests/fuzz_campaign.py --files 500 -o results/fuzz_campaign.json

Every case is a real clip (cut to `--frames` frames) with 1-3 mutations from `fuzz_files.py`,
in its own folder. Each goes through `extract --method all`, `extract --online --method
all`, `eval FOLDER`, `sheet`, `replay` to a loopback OSC sink and `run --from FILE --fast`:
in-process for speed (SIGALRM bounds each call: a hang), and every `--subprocess-every`-th
case also as real processes with a timeout. Counted per command: exit codes, tracebacks
(an exception escaping `main`, or "Traceback" on a real stderr), hangs, internal errors,
and error lines that do not name the file. The summary goes to stdout and `-o` as JSON.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import json
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fuzz_files import base_texts, random_ops, write_case  # noqa: E402

from streamkey.cli import main  # noqa: E402


class Hang(Exception):
    """A call did not return within the bound."""


def _expired(signum: int, frame: Any) -> None:
    raise Hang()


def commands(path: Path, tmp: Path, osc_port: int) -> dict[str, list[str]]:
    """The six command lines of one case."""
    return {
        "extract": ["extract", str(path), "--method", "all", "-q"],
        "extract_online": ["extract", str(path), "--online", "--method", "all", "-q"],
        "eval": ["eval", str(path.parent), "-q", "-o", str(tmp / "eval")],
        "sheet": ["sheet", str(path), "-o", str(tmp / "sheet.png")],
        "replay": ["replay", str(path), "--to", f"osc://127.0.0.1:{osc_port}", "--rate",
                   "100000"],
        "run": ["run", "--from", str(path), "--fast", "--to", f"jsonl:{tmp / 'events.jsonl'}"],
    }


def judge(code: int | None, err: str, path: Path) -> dict[str, Any]:
    """What one run shows: exit code, traceback, internal error, unnamed error lines."""
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    unnamed = [line for line in errors
               if str(path) not in line and str(path.parent) not in line]
    return {"code": code, "traceback": "Traceback" in err,
            "internal": "internal error" in err, "unnamed": unnamed[:1]}


def in_process(argv: list[str], bound: int) -> tuple[int | None, str, str | None]:
    """(exit code, stderr, escaped exception or 'hang') of `main(argv)`."""
    err = io.StringIO()
    out = io.TextIOWrapper(io.BytesIO(), encoding="utf-8")
    signal.alarm(bound)
    escaped = None
    code: int | None = None
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            code = main(argv)
    except Hang:
        escaped = "hang"
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 2
    except BaseException:  # noqa: BLE001 - counting them is the point
        escaped = traceback.format_exc(limit=-3)
    finally:
        signal.alarm(0)
    return code, err.getvalue(), escaped


def as_process(argv: list[str], bound: int) -> tuple[int | None, str, str | None]:
    try:
        done = subprocess.run([sys.executable, "-m", "streamkey", *argv], capture_output=True,
                              text=True, timeout=bound)
    except subprocess.TimeoutExpired:
        return None, "", "hang"
    return done.returncode, done.stderr, None


def drain(sock: socket.socket, stop: threading.Event) -> None:
    """The loopback OSC sink that replay sends to: read and forget."""
    sock.settimeout(0.2)
    while not stop.is_set():
        with contextlib.suppress(OSError):
            sock.recv(65536)


def campaign(n_files: int, seed: int, frames: int, every: int, bound: int) -> dict[str, Any]:
    """Run the campaign; returns the counts (and the first examples of each failure)."""
    bases = base_texts(frames)
    rng = random.Random(seed)
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    stop = threading.Event()
    threading.Thread(target=drain, args=(sink, stop), daemon=True).start()
    signal.signal(signal.SIGALRM, _expired)
    counts: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    examples: list[dict[str, Any]] = []
    started = time.monotonic()
    with tempfile.TemporaryDirectory() as root:
        for i in range(n_files):
            which = rng.choice(sorted(bases))
            ops = random_ops(rng)
            case = Path(root) / f"case{i:04d}"
            path = write_case(case / "clip", bases, which, ops)
            runs = [("inproc", in_process)] + ([("process", as_process)]
                                                if every and i % every == 0 else [])
            for mode, runner in runs:
                for name, argv in commands(path, case, sink.getsockname()[1]).items():
                    code, err, escaped = runner(argv, bound)
                    verdict = judge(code, err, path)
                    c = counts[f"{mode}:{name}"]
                    c["runs"] += 1
                    c[f"exit_{code}"] += 1
                    bad = []
                    if escaped == "hang":
                        bad.append("hang")
                    elif escaped is not None or verdict["traceback"]:
                        bad.append("traceback")
                    if verdict["internal"]:
                        bad.append("internal_error")
                    if verdict["unnamed"]:
                        bad.append("unnamed_error_line")
                    if code not in (0, 2) and escaped is None:
                        bad.append("other_exit_code")
                    if code == 2 and not err.strip():
                        bad.append("silent_exit_2")
                    for b in bad:
                        c[b] += 1
                    if bad and len(examples) < 40:
                        examples.append({"case": i, "file": which, "ops": ops, "command": name,
                                         "mode": mode, "problems": bad,
                                         "detail": (escaped or err)[-600:]})
            if (i + 1) % 50 == 0:
                print(f"[{i + 1}/{n_files}] {time.monotonic() - started:.0f} s",
                      file=sys.stderr, flush=True)
    stop.set()
    sink.close()
    totals: collections.Counter[str] = collections.Counter()
    for c in counts.values():
        totals.update(c)
    return {"files": n_files, "seed": seed, "frames": frames, "seconds":
            round(time.monotonic() - started, 1), "totals": dict(totals),
            "per_command": {k: dict(v) for k, v in sorted(counts.items())},
            "examples": examples}


def main_campaign() -> int:
    """Command line of the campaign; exit 1 if any run misbehaved."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--files", type=int, default=500)
    parser.add_argument("--seed", type=int, default=9)
    parser.add_argument("--frames", type=int, default=240, help="frames kept of each clip")
    parser.add_argument("--subprocess-every", type=int, default=25,
                        help="every Nth case also as real processes (0: never)")
    parser.add_argument("--bound", type=int, default=120, help="seconds before a run is a hang")
    parser.add_argument("-o", "--output", help="write the summary as JSON here")
    args = parser.parse_args()
    result = campaign(args.files, args.seed, args.frames, args.subprocess_every, args.bound)
    text = json.dumps(result, indent=1, default=str)
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        Path(args.output).write_text(text + "\n")
    t = result["totals"]
    print(json.dumps({k: t.get(k, 0) for k in ("runs", "exit_0", "exit_2", "traceback", "hang",
                                               "internal_error", "unnamed_error_line",
                                               "other_exit_code", "silent_exit_2")}))
    failures = sum(t.get(k, 0) for k in ("traceback", "hang", "internal_error",
                                          "unnamed_error_line", "other_exit_code",
                                          "silent_exit_2"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main_campaign())
