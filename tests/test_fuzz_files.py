"""Fuzz suite for the file boundary: mutated BVH/ASF/AMC through the CLI.

Every run must end with exit code 0 or 2, no traceback, no internal error, within a time
bound, and every error line must name the file. Hypothesis draws the mutations (see
`fuzz_files.py`) with `derandomize=True`, so CI replays the same cases every time; the CLI is
called in-process for speed (a SIGALRM bounds each call), plus real subprocesses for the
exit code and stderr as a user sees them. The bigger budget is `tests/fuzz_campaign.py`.
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from fuzz_files import KINDS, PAYLOADS, base_texts, write_case
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from streamkey.cli import main

BASES = base_texts(frames=60)
OPS = st.lists(st.tuples(st.sampled_from(KINDS), st.floats(0, 1, exclude_max=True),
                         st.sampled_from(PAYLOADS)), min_size=1, max_size=3)


def fuzz(examples: int) -> settings:
    """Deterministic, bounded: the same cases on every run, no example database."""
    return settings(derandomize=True, deadline=None, database=None, max_examples=examples,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])


BOUND_S = 20


@contextlib.contextmanager
def time_bound(seconds: int) -> Iterator[None]:
    """Fail (instead of hanging) when the body runs longer than `seconds`."""
    def expired(signum, frame):  # type: ignore[no-untyped-def]
        raise TimeoutError(f"no answer within {seconds} s: a hang")

    old = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def check_run(capsys: pytest.CaptureFixture[str], path: Path, *args: str) -> int:
    with time_bound(BOUND_S):
        code = main(list(args))
    _, err = capsys.readouterr()
    assert code in (0, 2), err
    assert "Traceback" not in err and "internal error" not in err, err
    for line in err.splitlines():
        if line.startswith("error:"):
            assert line.startswith(f"error: {path}") or str(path.parent) in line, line
    if code == 2:
        assert "error:" in err
    return code


@fuzz(60)
@given(which=st.sampled_from(["07_01.bvh", "16_11.bvh", "131_03.bvh"]), ops=OPS)
def test_mutated_bvh_through_extract_offline_and_online(capsys, which, ops) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = write_case(Path(tmp), BASES, which, ops)
        check_run(capsys, path, "extract", str(path), "--method", "all", "-q")
        check_run(capsys, path, "extract", str(path), "--online", "--method", "all", "-q")


@fuzz(60)
@given(which=st.sampled_from(["09.asf", "09_06.amc"]), ops=OPS)
def test_mutated_asf_and_amc_through_extract(capsys, which, ops) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = write_case(Path(tmp), BASES, which, ops)
        check_run(capsys, path, "extract", str(path), "--method", "saliency,speed,simplify",
                  "-q")
        check_run(capsys, path, "extract", str(path), "--online", "--method", "all", "-q")


@fuzz(15)
@given(which=st.sampled_from(["07_01.bvh", "09.asf", "09_06.amc"]), ops=OPS)
def test_mutated_files_through_eval_replay_and_run(capsys, which, ops) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = write_case(Path(tmp) / "clips", BASES, which, ops)
        check_run(capsys, path, "eval", str(path.parent), "-q", "-o", str(Path(tmp) / "ev"))
        check_run(capsys, path, "replay", str(path), "--to", "-", "--rate", "100000")
        capsys.readouterr()
        check_run(capsys, path, "run", "--from", str(path), "--fast", "--to",
                  f"jsonl:{Path(tmp) / 'e.jsonl'}", "--method", "saliency")


def test_a_few_mutations_as_real_processes(tmp_path) -> None:
    """Exit code and stderr exactly as a shell sees them, with a hard timeout."""
    cases = [("07_01.bvh", [("frames", 0.0, "")]),      # 0 frames: run used to hang
             ("07_01.bvh", [("frames", 0.3, "")]),      # 2 frames
             ("07_01.bvh", [("still", 0.0, "")]),       # a still pose
             ("09_06.amc", [("frames", 0.2, "")]),      # 1 AMC frame
             ("09.asf", [("line_delete", 0.4, "")])]
    for i, (which, ops) in enumerate(cases):
        path = write_case(tmp_path / str(i), BASES, which, ops)
        for args in (["extract", str(path), "--method", "all"],
                     ["run", "--from", str(path), "--fast", "--to",
                      f"jsonl:{tmp_path / f'e{i}.jsonl'}"]):
            done = subprocess.run([sys.executable, "-m", "streamkey", *args],
                                  capture_output=True, text=True, timeout=60)
            assert done.returncode in (0, 2), done.stderr
            assert "Traceback" not in done.stderr and "internal error" not in done.stderr
            if ops[0][0] == "still":  # a still clip is valid input, offline as online
                assert done.returncode == 0, done.stderr
            if done.returncode == 2:
                assert f"error: {path}" in done.stderr or f"{path.parent}" in done.stderr
