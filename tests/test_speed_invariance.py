"""Speed-minima keyposes (Miura et al. 2014) are keys of the motion, not of the recording:
the same take at 60 and 30 Hz, after a calibration hold, before stillness, or streamed with
its reference T-pose first, offline and online, against the clean take's keys."""

from __future__ import annotations

import numpy as np
import pytest
from cmu import clips
from invariance import case, count_ratio, f1, keys, load, variant

from streamkey.errors import UsageError
from streamkey.methods import speed
from streamkey.units import Duration

CLIPS = ["07_05.bvh", "02_01.bvh", "09_12.bvh", "06_02.bvh"]
VARIANTS = ["60 Hz", "30 Hz", "calibration", "stillness"]
MEAN_F1, WORST_F1, RATIOS = 0.9, 0.75, (0.8, 1.25)

# Unmet targets, as measured (mean F1, worst F1 (clip), count ratios).
XFAIL: dict[tuple[str, str], str] = {}
XFAIL_ALL: dict[tuple[str, str], str] = {
    ("30 Hz", "offline"): "measured: mean F1 0.968, worst 0.77 (05_13), ratios 0.62-1.02",
    ("calibration", "online"): "measured: mean F1 0.952, worst 0.75 (49_18.amc), ratios "
                               "0.71-1.25",
}


def check(names: list[str], which: str, mode: str) -> None:
    scores = {n: f1("speed", mode, n, which) for n in names}
    ratios = {n: count_ratio("speed", mode, n, which) for n in names}
    worst = min(scores, key=scores.__getitem__)
    summary = (f"mean F1 {np.mean(list(scores.values())):.3f}, worst {scores[worst]:.2f} "
               f"({worst}), ratios {min(ratios.values()):.2f}-{max(ratios.values()):.2f}")
    assert np.mean(list(scores.values())) >= MEAN_F1, summary
    assert scores[worst] >= WORST_F1, summary
    assert all(RATIOS[0] <= r <= RATIOS[1] for r in ratios.values()), summary


@pytest.mark.parametrize(("which", "mode"), [case(w, m, XFAIL) for w in VARIANTS
                                             for m in ("offline", "online")])
def test_keys_of_a_variant_are_the_clean_takes_keys(which: str, mode: str) -> None:
    check(CLIPS, which, mode)


@pytest.mark.slow
@pytest.mark.parametrize(("which", "mode"), [case(w, m, XFAIL_ALL) for w in VARIANTS
                                             for m in ("offline", "online")])
def test_keys_of_a_variant_are_the_clean_takes_keys_on_every_clip(which: str, mode: str) -> None:
    check(clips(), which, mode)


@pytest.mark.parametrize("mode", ["offline", "online"])
def test_a_reference_t_pose_streamed_first_changes_no_key(mode: str) -> None:
    """A sender of the whole cgspeed file starts with its reference T-pose: one frame whose
    jump into the take was the largest speed of the stream (07_05: 1 key instead of 6)."""
    for name in CLIPS:
        clean = keys("speed", mode, name, "clean")
        assert np.array_equal(keys("speed", mode, name, "reference first"), clean), name


def test_duration_defaults_are_the_old_frame_counts_at_120_hz_and_follow_the_rate() -> None:
    m = load("07_05.bvh")
    at120 = speed.Online(m.skeleton, 120.0)
    assert (at120.lookahead, at120.hop, at120.history, at120.cutoff_history) == (120, 24, 2400,
                                                                                 7200)
    at30 = speed.Online(m.skeleton, 30.0)
    assert (at30.lookahead, at30.hop, at30.history, at30.cutoff_history) == (30, 6, 600, 1800)
    frames = speed.Online(m.skeleton, 30.0, lookahead=60, hop=Duration.seconds(0.5))
    assert (frames.lookahead, frames.hop) == (60, 15)  # plain numbers stay frames
    with pytest.raises(UsageError, match="lookahead"):
        speed.Online(m.skeleton, 30.0, lookahead=Duration.seconds(0.05))


def test_rest_is_no_candidate() -> None:
    """An exact hold leaves rounding noise and HP ringing; no candidate lies there."""
    v = variant("07_05.bvh", "stillness")
    k = speed.extract(v.motion)
    end = v.take_end
    assert k.info["candidates"].max() < end + 60  # ringing of the stop: under 0.5 s
    assert len(keys("speed", "offline", "07_05.bvh", "stillness")) >= 1


@pytest.mark.parametrize("which", ["30 Hz", "stillness", "reference first"])
def test_online_with_unbounded_lookahead_equals_offline_on_a_variant(which: str) -> None:
    m = variant("07_05.bvh", which).motion
    kf = speed.Online(m.skeleton, m.fps, lookahead=m.n_frames + 1)
    events = kf.push_block(m.frames()) + kf.flush()
    off = speed.extract(m)
    assert [e.frame for e in events] == off.frames.tolist()
    assert [e.score for e in events] == off.scores.tolist()
