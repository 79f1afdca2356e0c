"""Keys of a shared clip's recording variants, offline and online, as clean-take frames.

A keypose is a property of the motion: the same take at another rate, after a calibration
hold, before stillness or streamed with its reference T-pose first should give the clean
take's keys. Online keys are compared with the online keys of the clean take (the same
keyframer, the same defaults), offline with offline.
"""

from __future__ import annotations

from functools import cache
from types import ModuleType

import numpy as np
import pytest
from cmu import DATA

from streamkey import variants as V
from streamkey.amc import read_motion
from streamkey.evaluate import error_e, reconstruct
from streamkey.methods import simplify, speed
from streamkey.motion import Motion

METHODS: dict[str, ModuleType] = {"speed": speed, "simplify": simplify}
MODES = ("offline", "online")


@cache
def load(name: str) -> Motion:
    """A shared clip, BVH or AMC (a cgspeed reference frame is skipped by the reader)."""
    return read_motion(DATA / name)


@cache
def variant(name: str, which: str) -> V.Variant:
    """`which` of clip `name`: clean, 60 Hz, 30 Hz, calibration, stillness, reference first
    (the file's reference T-pose streamed before the take, as a sender of the whole file)."""
    m = load(name)
    if which == "clean":
        return V.clean_take(m)
    if which.endswith(" Hz"):
        return V.resample(m, float(which.split()[0]))
    if which == "calibration":
        return V.with_calibration(m)
    if which == "stillness":
        return V.with_stillness(m)
    if which == "reference first":
        assert m.first_frame == 1, name
        ref = Motion(m.skeleton, m.channels, m.fps, 0, m.name + "+reference")
        return V.Variant(which, ref, m.fps, 1, 1)
    raise ValueError(which)


def run(method: str, mode: str, motion: Motion) -> np.ndarray:
    """Keyframes of `motion` (its own frame numbers): `extract`, or the online keyframer with
    its defaults fed every frame from frame `motion.first_frame` on, then flushed."""
    mod = METHODS[method]
    if mode == "offline":
        return np.asarray(mod.extract(motion).frames)
    kf = mod.Online(motion.skeleton, motion.fps)
    events = kf.push_block(motion.frames()) + kf.flush()
    last = motion.n_frames - 1  # flush() decides the rest at the last frame
    bound = kf.lookahead + kf.features.delay  # the noise front end holds `delay` frames
    assert all(e.latency_frames <= bound for e in events if e.decided_at < last)
    return np.array(sorted(e.frame for e in events), dtype=np.int64)


@cache
def keys(method: str, mode: str, name: str, which: str) -> np.ndarray:
    """Keys of a variant inside the take, as (fractional) clean-take frame numbers."""
    v = variant(name, which)
    return V.keys_in_take(v, run(method, mode, v.motion))


def f1(method: str, mode: str, name: str, which: str) -> float:
    """F1 (±4 frames at 120 Hz) of a variant's keys against the clean take's."""
    clean = keys(method, mode, name, "clean")
    return V.f1_against(clean, keys(method, mode, name, which), load(name).fps)


def count_ratio(method: str, mode: str, name: str, which: str) -> float:
    """Variant key count over the clean take's."""
    return len(keys(method, mode, name, which)) / len(keys(method, mode, name, "clean"))


def e_ratio(method: str, mode: str, name: str, which: str) -> float:
    """E of the clean motion rebuilt from the variant's keys (mapped back, rounded) over E
    rebuilt from the clean take's keys."""
    clean = variant(name, "clean").motion

    def e(frames: np.ndarray) -> float:
        rows = np.unique(np.clip(np.round(frames).astype(np.int64), 0, clean.n_frames - 1))
        return error_e(clean, reconstruct(clean, rows))

    return e(keys(method, mode, name, which)) / e(keys(method, mode, name, "clean"))


def case(which: str, mode: str, table: dict[tuple[str, str], str]) -> object:
    """A (variant, mode) test case, a strict expected failure when `table` holds its
    measured miss."""
    reason = table.get((which, mode))
    marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
    return pytest.param(which, mode, marks=marks, id=f"{which}-{mode}")
