"""Sessions built from the shared takes (`streamkey.sessions`): what the agreement goal's
session corpus is made of."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest
from cmu import DATA

from streamkey.amc import read_motion
from streamkey.errors import UsageError
from streamkey.evaluate import _unwrapped
from streamkey.sessions import (
    BLEND_S,
    HOLD_S,
    MAX_SECONDS,
    MIN_SECONDS,
    Session,
    build_session,
    read_sessions,
    subject_takes,
)


@cache
def sessions() -> tuple[Session, ...]:
    return tuple(read_sessions(DATA))


def test_every_subject_with_two_takes_makes_one_session_of_one_to_ten_minutes() -> None:
    groups = subject_takes(sorted(DATA.iterdir()))
    assert list(groups) == ["01", "02", "05", "06", "07", "09", "131"]
    assert [s.name for s in sessions()] == [f"session {g}" for g in groups]
    for session in sessions():
        assert MIN_SECONDS <= session.seconds <= MAX_SECONDS, session.name
        assert session.motion.fps == 120.0 and session.motion.first_frame == 0


def test_takes_come_in_their_own_order_all_of_them_first() -> None:
    groups = subject_takes(sorted(DATA.iterdir()))
    for session, paths in zip(sessions(), groups.values(), strict=True):
        names = [t.name for t in session.takes]
        stems = [p.stem for p in paths]
        assert names[: len(stems)] == stems, session.name
        for i, take in enumerate(session.takes):  # later rounds repeat the list
            assert take.name == stems[i % len(stems)] and take.round == i // len(stems)


def test_each_take_is_the_clip_itself_moved_on_the_ground() -> None:
    session = sessions()[0]  # subject 01: 4 takes, 127 s
    skel = session.motion.skeleton
    rot = skel.rotation_columns()
    pos = skel.position_columns()
    for take in session.takes:
        clip = read_motion(DATA / f"{take.name}.bvh")
        x = session.motion.channels[take.start : take.end]
        own = _unwrapped(clip)
        assert len(x) == clip.n_frames - clip.first_frame
        np.testing.assert_array_equal(x[:, rot], own[:, rot])
        shift = x[:, pos] - own[:, pos]
        np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-9)
        assert shift[0][1] == pytest.approx(0.0)  # the height is the take's own (Y up)


def test_transitions_hold_then_blend_with_no_jump_of_the_root() -> None:
    fps = 120.0
    hold, blend = round(HOLD_S * fps), round(BLEND_S * fps)
    for session in sessions():
        x = session.motion.channels
        pos = session.motion.skeleton.position_columns()
        for prev, take in zip(session.takes[:-1], session.takes[1:], strict=True):
            assert take.start - prev.end == hold + blend, session.name
            gap = x[prev.end - 1 : take.start + 1]
            np.testing.assert_array_equal(gap[: hold + 1], np.repeat(gap[:1], hold + 1, 0))
            ground = pos[[0, 2]]
            assert np.allclose(x[prev.end - 1, ground], x[take.start, ground]), session.name
            steps = np.abs(np.diff(gap[:, pos], axis=0)).max()
            assert steps < 2.0, (session.name, take.name, steps)  # cm a frame, no jump


def test_bad_session_input_raises_a_usage_error(tmp_path: Path) -> None:
    walk = read_motion(DATA / "07_01.bvh")
    hop = read_motion(DATA / "131_03.bvh")  # another skeleton (3ds Max joint names)
    with pytest.raises(UsageError, match="does not match"):
        build_session("mixed", [walk, hop])
    with pytest.raises(UsageError, match="no takes"):
        build_session("empty", [])
    with pytest.raises(UsageError, match="no subject 99"):
        read_sessions(DATA, ["99"])
    with pytest.raises(UsageError, match="no folder"):
        read_sessions(tmp_path / "missing")


def test_a_short_session_keeps_its_takes_and_stops_at_the_minimum() -> None:
    walk = read_motion(DATA / "07_01.bvh")
    session = build_session("walks", [walk], min_seconds=10.0, max_seconds=20.0)
    per_take = (walk.n_frames - walk.first_frame) / walk.fps
    more = int(np.ceil((10.0 - per_take) / (per_take + HOLD_S + BLEND_S)))
    assert len(session.takes) == 1 + more  # the first take has no transition before it
    assert 10.0 <= session.seconds <= 20.0
    assert session.frame_at(10.0) == 1200
