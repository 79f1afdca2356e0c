"""Record the golden outputs that `tests/test_golden.py` keeps: run when behaviour changes on
purpose (`.venv/bin/python -P tests/golden/record.py`, from the repository root), then read
the diff of tests/golden/*.json* before committing it.

What is recorded, each through the real command line:

- `streamkey extract --method all` on CLIPS, offline and `--online` (extract_offline.json,
  extract_online.json; file paths reduced to the file name);
- the JSON Lines event log of `streamkey run --fast --method all` fed by `streamkey replay
  --to -` on stdin (run_stdin_CLIP.jsonl), once more with `--provisional --signal`
  (run_stdin_playable_CLIP.jsonl), and by `streamkey replay --to osc://...` over loopback
  UDP (run_osc_CLIP.jsonl).

Wall-clock fields (`wall_latency_ms`) are dropped before storing: they differ on every run.
An OSC run only counts if it lost nothing (`osc_run` returns its accounting): UDP and the
drop-oldest frame queue may drop frames on a loaded machine, and the recording refuses one
that did.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
DATA = ROOT.parent / "shared" / "data" / "cmu"

# ten varied clips: a long one (01_06, 5134 frames), AMC (05_11, 07_05, 49_18), dance (05_11,
# 05_13), very short runs (02_03, 09_06), sword, basketball, hops
CLIPS = ["01_06.bvh", "02_03.bvh", "02_07.bvh", "05_11.amc", "05_13.bvh", "06_02.bvh",
         "07_05.amc", "09_06.bvh", "49_18.amc", "131_03.bvh"]
RUN_CLIPS = ["09_06.bvh", "05_11.amc", "07_01.bvh"]  # run: stdin and OSC
PLAYABLE_CLIP = "09_06.bvh"
WALL_CLOCK = frozenset({"wall_latency_ms"})  # fields that measure the machine, not the method
TIMEOUT = 1800.0


def streamkey(*args: str, **kwargs: Any) -> subprocess.Popen[str]:
    """Start `python -P -m streamkey ARGS` (stdout and stderr piped)."""
    return subprocess.Popen([sys.executable, "-P", "-m", "streamkey", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            **kwargs)


def clip(name: str) -> str:
    """Path of a shared CMU clip."""
    return str(DATA / name)


def extract(clips: list[str], online: bool) -> dict[str, Any]:
    """`extract --method all` (or `--online`) of `clips`, file paths reduced to names."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "extract.json"
        args = ["extract", *map(clip, clips), "--method", "all", "-q", "-o", str(out)]
        proc = streamkey(*args, *(["--online"] if online else []))
        _, err = proc.communicate(timeout=TIMEOUT)
        if proc.returncode != 0:
            raise RuntimeError(f"extract failed: {err}")
        result: dict[str, Any] = json.loads(out.read_text())
    for entry in result["files"]:
        entry["file"] = Path(entry["file"]).name
    return result


def strip_wall_clock(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The events without their wall-clock measurements."""
    return [{k: v for k, v in e.items() if k not in WALL_CLOCK} for e in events]


def read_log(path: Path) -> list[dict[str, Any]]:
    """Every event of a JSON Lines log, in order."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def stdin_run(name: str, extra: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """`replay CLIP --to - | run --from - --fast --method all`: the event log, in order."""
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "events.jsonl"
        replay = subprocess.Popen([sys.executable, "-P", "-m", "streamkey", "replay",
                                   clip(name), "--to", "-", "--rate", "100000"], cwd=ROOT,
                                  stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        run = streamkey("run", "--from", "-", "--fast", "--method", "all",
                        "--to", f"jsonl:{log}", *extra, stdin=replay.stdout)
        assert replay.stdout is not None
        replay.stdout.close()
        _, err = run.communicate(timeout=TIMEOUT)
        replay.wait(timeout=TIMEOUT)
        if run.returncode != 0 or replay.returncode != 0:
            raise RuntimeError(f"stdin run of {name} failed: {err}")
        return strip_wall_clock(read_log(log))


def free_udp_port() -> int:
    """A UDP port free on 127.0.0.1 now, whose successor is free too (the OSC source may
    answer from the next one)."""
    for _ in range(50):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s2:
                s2.bind(("127.0.0.1", port + 1))
            return port
        except OSError:
            continue
    raise RuntimeError("no free UDP port pair on 127.0.0.1")


def _wait_ready(proc: subprocess.Popen[str], needle: str = "listening on") -> None:
    assert proc.stderr is not None
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            raise RuntimeError("run ended before its ready line")
        if needle in line:
            return
    raise RuntimeError("no ready line")


def osc_run(name: str) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """`replay CLIP --to osc://127.0.0.1:PORT` into `run --from osc://... --fast --method
    all --skeleton CLIP`: the event log, in order, and the run's accounting (whether any
    frame was dropped on the way: see `lossless`)."""
    port = free_udp_port()
    address = f"osc://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as tmp:
        log, summary = Path(tmp) / "events.jsonl", Path(tmp) / "summary.json"
        run = streamkey("run", "--from", address, "--skeleton", clip(name), "--fast",
                        "--method", "all", "--to", f"jsonl:{log}", "--summary", str(summary),
                        "--idle-exit", "2")
        try:
            _wait_ready(run)
            replay = streamkey("replay", clip(name), "--to", address)
            _, replay_err = replay.communicate(timeout=TIMEOUT)
            if replay.returncode != 0:
                raise RuntimeError(f"replay of {name} failed: {replay_err}")
            _, err = run.communicate(timeout=TIMEOUT)
        finally:
            if run.poll() is None:
                run.kill()
                run.communicate()
        if run.returncode != 0:
            raise RuntimeError(f"OSC run of {name} failed: {err}")
        accounting: dict[str, Any] = json.loads(summary.read_text())["accounting"]
        return strip_wall_clock(read_log(log)), accounting


def lossless(accounting: dict[str, Any]) -> bool:
    """True if every frame sent reached the keyframers (no UDP, queue or seq loss)."""
    return (accounting["queue_drops"] == 0 and accounting["never_arrived"] == 0
            and not accounting["kernel_drops"] and not sum(accounting["malformed"].values())
            and accounting["left_in_queue"] == 0)


def golden_path(kind: str, name: str = "") -> Path:
    """Where a golden output is stored."""
    if kind.startswith("extract"):
        return HERE / f"{kind}.json"
    return HERE / f"{kind}_{Path(name).stem}.jsonl"


def write_log(path: Path, events: list[dict[str, Any]]) -> None:
    """Store events one JSON object a line (keys in the order the sink wrote them)."""
    path.write_text("".join(json.dumps(e) + "\n" for e in events))


def main() -> None:
    """Record every golden output (minutes: the long clip's offline methods dominate)."""
    for online in (False, True):
        kind = "extract_online" if online else "extract_offline"
        golden_path(kind).write_text(json.dumps(extract(CLIPS, online), indent=1) + "\n")
        print(f"recorded {kind}", flush=True)
    for name in RUN_CLIPS:
        write_log(golden_path("run_stdin", name), stdin_run(name))
        events, accounting = osc_run(name)
        if not lossless(accounting):
            raise RuntimeError(f"OSC run of {name} lost frames ({accounting}); record again "
                               "on a quieter machine")
        write_log(golden_path("run_osc", name), events)
        print(f"recorded runs of {name}", flush=True)
    write_log(golden_path("run_stdin_playable", PLAYABLE_CLIP),
              stdin_run(PLAYABLE_CLIP, ("--provisional", "--signal")))
    print("recorded the playable run", flush=True)


if __name__ == "__main__":
    os.chdir(ROOT)
    main()
