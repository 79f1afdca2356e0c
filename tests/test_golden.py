"""Golden outputs: `extract` (offline and online) and `run`'s event log (over stdin and OSC)
equal what `tests/golden/record.py` recorded at the base of the engine refactor.

Portable across CPUs: every discrete field (frames, counts, ids, method names, types,
decided_at, latency_frames, the order of events) must be equal; floats (score, time,
strength, thresholds) within a relative 1e-9, or 1.5e-6 absolute: the JSON rounds them to 6
decimals, and a last-bit difference of another CPU's arithmetic may move the rounding by one
unit (1e-6, plus its binary error). Wall-clock measurements (`wall_latency_ms`) are not recorded.

Over OSC (loopback UDP, paced at the clip's rate, frames into a drop-oldest queue) a loaded
machine may lose frames; such a run is skipped, saying what was lost. The stdin runs (a pipe
that blocks, never drops) are the strict ones.
"""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
from golden.record import (
    CLIPS,
    PLAYABLE_CLIP,
    RUN_CLIPS,
    WALL_CLOCK,
    extract,
    golden_path,
    lossless,
    osc_run,
    read_log,
    stdin_run,
)

REL_TOL = 1e-9
ABS_TOL = 1.5e-6  # one unit of the 6th decimal (events and results are rounded to 6), and
# the binary error of that decimal difference


def differences(want: Any, got: Any, where: str = "") -> list[str]:
    """Where `got` differs from `want` (floats within REL_TOL / ABS_TOL, the rest exactly)."""
    if isinstance(want, dict) and isinstance(got, dict):
        out = []
        keys = set(want) - WALL_CLOCK, set(got) - WALL_CLOCK
        if keys[0] != keys[1]:
            out.append(f"{where}: keys {sorted(keys[0] ^ keys[1])} in one side only")
        for key in sorted(keys[0] & keys[1]):
            out += differences(want[key], got[key], f"{where}.{key}")
        return out
    if isinstance(want, list) and isinstance(got, list):
        if len(want) != len(got):
            return [f"{where}: {len(got)} items, expected {len(want)}"]
        return [d for i, (w, g) in enumerate(zip(want, got, strict=True))
                for d in differences(w, g, f"{where}[{i}]")]
    if isinstance(want, float) or isinstance(got, float):
        if (isinstance(want, float) and isinstance(got, float)
                and math.isclose(want, got, rel_tol=REL_TOL, abs_tol=ABS_TOL)):
            return []
        return [f"{where}: {got!r}, expected {want!r}"]
    if type(want) is not type(got) or want != got:
        return [f"{where}: {got!r}, expected {want!r}"]
    return []


def assert_same(want: Any, got: Any) -> None:
    """Fail listing the first differences."""
    found = differences(want, got)
    assert not found, f"{len(found)} differences from the golden output:\n" + "\n".join(
        found[:20])


def test_the_comparison_is_exact_on_discrete_fields_and_tolerant_on_floats() -> None:
    assert not differences({"score": 1.0, "frame": 3}, {"score": 1.0 + 1e-12, "frame": 3})
    assert not differences({"score": 0.123456}, {"score": 0.123457})  # a rounding flip
    assert differences({"score": 0.12345}, {"score": 0.12355})
    assert differences({"frame": 3}, {"frame": 4})
    assert differences({"frame": 3}, {"frame": 3.0})
    assert differences([1, 2], [2, 1])  # order matters
    assert differences({"id": "a/b/1"}, {"id": "a/b/2"})
    assert not differences({"wall_latency_ms": 1.0}, {"wall_latency_ms": 9.0})


@pytest.mark.parametrize("name", RUN_CLIPS)
def test_run_over_stdin_writes_the_golden_event_log(name: str) -> None:
    assert_same(read_log(golden_path("run_stdin", name)), stdin_run(name))


def test_run_over_stdin_with_provisional_and_signal_events_writes_the_golden_log() -> None:
    assert_same(read_log(golden_path("run_stdin_playable", PLAYABLE_CLIP)),
                stdin_run(PLAYABLE_CLIP, ("--provisional", "--signal")))


@pytest.mark.parametrize("name", RUN_CLIPS)
def test_run_over_osc_writes_the_golden_event_log(name: str) -> None:
    events, accounting = osc_run(name)
    if not lossless(accounting):
        pytest.skip(f"frames were lost on the way (a loaded machine): {json.dumps(accounting)}")
    assert_same(read_log(golden_path("run_osc", name)), events)


@pytest.mark.slow
@pytest.mark.parametrize("online", [False, True], ids=["offline", "online"])
def test_extract_writes_the_golden_json(online: bool) -> None:
    kind = "extract_online" if online else "extract_offline"
    assert_same(json.loads(golden_path(kind).read_text()), extract(CLIPS, online))
