"""`run --from -`: JSON Lines frames on stdin, the format `replay --to -` writes."""

from __future__ import annotations

import asyncio
import io
import json
import random
import subprocess
import sys

import pytest
from cmu import DATA
from live_helpers import MS, read_jsonl

from streamkey.adapters.jsonl_source import MAX_LINE_BYTES, StdinSource, read_skeleton_line
from streamkey.bvh import read_bvh
from streamkey.errors import InputError
from streamkey.framequeue import FrameArrived
from streamkey.methods import ONLINE_METHODS

CLIP = DATA / "07_01.bvh"
CMD = [sys.executable, "-m", "streamkey"]


def _keys(events: list[dict]) -> list[tuple]:
    return sorted((e["method"], e["frame"], e["decided_at"], e["score"]) for e in events
                  if e["type"] == "keyframe")


def test_replay_to_stdout_piped_into_run_from_stdin_equals_run_from_the_file(tmp_path):
    piped, direct = tmp_path / "piped.jsonl", tmp_path / "direct.jsonl"
    replay = subprocess.Popen([*CMD, "replay", str(CLIP), "--to", "-", "--rate", "3000"],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    run = subprocess.run([*CMD, "run", "--from", "-", "--to", f"jsonl:{piped}"],
                         stdin=replay.stdout, capture_output=True, text=True, timeout=120 * MS)
    assert replay.stdout is not None
    replay.stdout.close()
    assert replay.wait(timeout=60 * MS) == 0
    assert run.returncode == 0, run.stderr
    assert "frames in: 316" in run.stderr and "malformed: 0" in run.stderr
    ref = subprocess.run([*CMD, "run", "--from", str(CLIP), "--fast", "--to", f"jsonl:{direct}"],
                         capture_output=True, text=True, timeout=120 * MS)
    assert ref.returncode == 0, ref.stderr
    got, want = _keys(read_jsonl(piped)), _keys(read_jsonl(direct))
    assert got == want and {k[0] for k in want} == set(ONLINE_METHODS)


def test_stdin_without_a_skeleton_line_is_one_clear_error():
    run = subprocess.run([*CMD, "run", "--from", "-"], input='{"seq": 1, "channels": [1]}\n',
                         capture_output=True, text=True, timeout=60 * MS)
    assert run.returncode == 2
    assert run.stderr.startswith("error: stdin:1: expected a skeleton line")
    assert "Traceback" not in run.stderr and run.stderr.count("\n") == 1
    with pytest.raises(InputError, match="ended before a skeleton line"):
        read_skeleton_line(io.BytesIO(b"\n\n"))


def _garbage(rng: random.Random, good: bytes) -> bytes:
    kind = rng.randrange(7)
    if kind == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 80))).replace(b"\n", b"")
    if kind == 1:
        cut = rng.randrange(1, len(good) - 1)
        return good[:cut]
    if kind == 2:
        return b'{"seq": "x", "channels": [1, 2]}'
    if kind == 3:
        return b'{"seq": 5, "channels": [1, "a"]}'
    if kind == 4:
        return b"[1, 2, 3]"
    if kind == 5:
        return b'{"seq": 5, "channels": [' + b"1," * 2000 + b"1]}"
    return b'{"seq": 5, "time": true, "channels": [1]}'


def _collect(source: StdinSource) -> list:
    async def main() -> list:
        await source.start()
        out = []
        while isinstance(item := await asyncio.wait_for(source.get(), 10 * MS), FrameArrived):
            out.append(item.frame)
        await source.close()
        return out

    return asyncio.run(main())


def test_fuzzed_lines_are_dropped_and_counted_never_raised():
    motion = read_bvh(CLIP)
    rng = random.Random(11)
    good_lines = [json.dumps({"seq": f.seq, "time": f.time, "channels": f.channels.tolist()})
                  .encode() for f in motion.frames()[:60]]
    lines, bad = [], 0
    for g in good_lines:
        lines.append(g)
        for _ in range(rng.randrange(3)):
            lines.append(_garbage(rng, g))
            bad += 1
    lines.append(b" ")
    lines.append(b"x" * (MAX_LINE_BYTES + 10))  # over the limit: dropped whole, counted
    bad += 1
    source = StdinSource(motion.skeleton, motion.fps, io.BytesIO(b"\n".join(lines) + b"\n"))
    frames = _collect(source)
    assert [f.seq for f in frames] == [f.seq for f in motion.frames()[:60]]
    assert sum(source.stats.malformed.values()) == bad
    assert source.stats.received == 60


def test_run_from_stdin_with_random_bytes_exits_cleanly(tmp_path):
    rng = random.Random(5)
    noise = bytes(rng.randrange(256) for _ in range(20000))
    run = subprocess.run([*CMD, "run", "--from", "-", "--skeleton", str(CLIP)], input=noise,
                         capture_output=True, timeout=60 * MS)
    err = run.stderr.decode()
    assert run.returncode == 0, err
    assert "Traceback" not in err and "frames in: 0" in err
    assert "malformed: 0" not in err


def test_positions_only_frames_are_refused_with_a_clear_reason():
    line = b'{"seq": 1, "joints": {"head": [0, 1.7, 0]}}\n'
    with pytest.raises(InputError, match=r"stdin:1: positions-only frames .* rotation channels"):
        read_skeleton_line(io.BytesIO(line))
    motion = read_bvh(CLIP)
    source = StdinSource(motion.skeleton, motion.fps, io.BytesIO(line * 3))
    assert _collect(source) == []
    assert source.stats.malformed["positions_only"] == 3
    assert "positions-only" in source.stats.last_error


def test_deep_json_and_out_of_range_numbers_are_counted_and_the_stream_goes_on():
    motion = read_bvh(CLIP)
    good = [json.dumps({"seq": f.seq, "time": f.time, "channels": f.channels.tolist()}).encode()
            for f in motion.frames()[:5]]
    hostile = [b'{"seq": ' + b"[" * 100_000, b'{"seq": 1e30, "channels": [1]}',
               b'{"seq": 7, "time": 1e300, "channels": [1]}']
    source = StdinSource(motion.skeleton, motion.fps,
                         io.BytesIO(b"\n".join(good[:2] + hostile + good[2:]) + b"\n"))
    frames = _collect(source)
    assert [f.seq for f in frames] == [f.seq for f in motion.frames()[:5]]
    assert sum(source.stats.malformed.values()) == len(hostile)
    assert source.fatal is None


@pytest.mark.parametrize("fps", [1e-6, 0, 1e9, "nan"])
def test_a_skeleton_line_with_an_unusable_frame_rate_is_one_clear_error(fps):
    text = CLIP.read_text()
    line = json.dumps({"type": "skeleton", "bvh": text[: text.index("MOTION")], "fps": fps})
    with pytest.raises(InputError, match="expected a skeleton line"):
        read_skeleton_line(io.BytesIO(line.encode() + b"\n"))
