"""Helpers for tests that run streamkey processes on loopback."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

MS = float(os.environ.get("STREAMKEY_TEST_TIME_FACTOR", "1"))  # scale every timeout


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port that is free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def streamkey(*args: str, **kwargs) -> subprocess.Popen:
    """Start `python -m streamkey ARGS` with stdout and stderr piped."""
    return subprocess.Popen([sys.executable, "-m", "streamkey", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kwargs)


def interrupt_if_running(proc: subprocess.Popen, timeout: float = 30.0) -> None:
    """Test cleanup: Ctrl-C a process that is still running and reap it."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=timeout)


def wait_ready(proc: subprocess.Popen, needle: str = "listening on",
               timeout: float = 30.0) -> list[str]:
    """Read stderr lines until one contains `needle` (the ready line); returns them."""
    lines = []
    deadline = time.monotonic() + timeout * MS
    assert proc.stderr is not None
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            raise AssertionError(f"process ended before ready: {''.join(lines)}")
        lines.append(line)
        if needle in line:
            return lines
    raise AssertionError(f"no ready line within {timeout} s: {''.join(lines)}")


def read_jsonl(path: Path) -> list[dict]:
    """Every event of a JSON Lines log."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def keyframes_of(events: list[dict]) -> list[tuple[str, int, int]]:
    """(method, frame, decided_at) of every keyframe event, sorted."""
    return sorted((e["method"], e["frame"], e["decided_at"]) for e in events
                  if e["type"] == "keyframe")


def wait_udp_bound(port: int, what: str, timeout: float = 20.0) -> None:
    """For peers that print no ready line (oscdump, Pd): wait until their UDP port is taken."""
    deadline = time.monotonic() + timeout * MS
    while time.monotonic() < deadline:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:
                return
        time.sleep(0.02)
    raise AssertionError(f"{what} did not bind UDP port {port}")


async def until(predicate, seconds: float = 10.0) -> None:
    """Wait (on the running loop) until `predicate()` holds; fail after `seconds`."""
    deadline = asyncio.get_running_loop().time() + seconds * MS
    while not predicate():
        assert asyncio.get_running_loop().time() < deadline, "condition not reached in time"
        await asyncio.sleep(0.002)


def keys_sent_to_osc(clip: Path, port: int, log: Path) -> list[dict]:
    """`streamkey run` over a clip (speed and simplify, stream "take 1") to an OSC port and a
    JSON Lines log; the keyframe events it logged."""
    run = streamkey("run", "--from", str(clip), "--fast", "--method", "speed,simplify",
                    "--stream", "take 1", "--to", f"osc://127.0.0.1:{port}",
                    "--to", f"jsonl:{log}")
    _, err = run.communicate(timeout=120 * MS)
    assert run.returncode == 0, err
    return [e for e in read_jsonl(log) if e["type"] == "keyframe"]


def run_with_handler(coro):
    """asyncio.run, failing on any exception that reached the loop (a traceback)."""
    problems = []

    async def main():
        asyncio.get_running_loop().set_exception_handler(lambda loop, ctx: problems.append(ctx))
        return await coro

    result = asyncio.run(main())
    assert not problems, problems
    return result
