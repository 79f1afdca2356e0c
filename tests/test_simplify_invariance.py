"""Curve-simplification keyframes (Lowe; Lim & Thalmann; Önder et al.) are keys of the
motion, not of the recording: the same take at 60 and 30 Hz, after a calibration hold or
before stillness, offline and online, keeps the clean take's key count and, rebuilt from its
keys (mapped back to the clean take), the clean take's error E."""

from __future__ import annotations

import pytest
from cmu import clips
from invariance import case, count_ratio, e_ratio, f1, load, variant

from streamkey.errors import UsageError
from streamkey.methods import simplify
from streamkey.units import Duration

CLIPS = ["07_05.bvh", "02_01.bvh", "09_12.bvh", "06_02.bvh"]
VARIANTS = ["60 Hz", "30 Hz", "calibration", "stillness"]
ODD_RATES = ["90 Hz", "100 Hz"]  # not a power of two from 120 Hz
RATIOS, MAX_E_RATIO = (0.8, 1.25), 1.10

# Unmet targets, as measured (count ratios, largest E ratio), behind the 5 Hz noise filter.
XFAIL: dict[tuple[str, str], str] = {}
XFAIL_ALL: dict[tuple[str, str], str] = {  # key counts within 0.80-1.25 everywhere
    ("30 Hz", "offline"): "measured: E ratio above 1.10 on 2 of 35 clips, at most 1.23 (03_01): "
                          "the take's last 3 frames are not in the 30 Hz take, and the last "
                          "chord without them meets the tolerance",
    ("30 Hz", "online"): "measured: E ratio above 1.10 on 1 of 35 clips, 1.23 (03_01)",
    ("calibration", "offline"): "measured: E ratio above 1.10 on 7 of 35, at most 1.97 (07_01): "
                                "the hold before the take moves the frame numbers, so the "
                                "split grid lies elsewhere in the take",
    ("calibration", "online"): "measured: E ratio above 1.10 on 8 of 35, at most 1.97 (07_01)",
    ("stillness", "offline"): "measured: E ratio above 1.10 on 1 of 35, 1.13 (35_01.amc): with "
                              "stillness after it the take's last frame is no key",
    ("stillness", "online"): "measured: E ratio above 1.10 on 1 of 35, 1.13 (35_01.amc)",
}


def check(names: list[str], which: str, mode: str) -> None:
    ratios = {n: count_ratio("simplify", mode, n, which) for n in names}
    errors = {n: e_ratio("simplify", mode, n, which) for n in names}
    summary = f"count ratios {ratios}, E ratios {errors}"
    assert all(RATIOS[0] <= r <= RATIOS[1] for r in ratios.values()), summary
    assert all(e <= MAX_E_RATIO for e in errors.values()), summary


@pytest.mark.parametrize(("which", "mode"), [case(w, m, XFAIL) for w in VARIANTS
                                             for m in ("offline", "online")])
def test_a_variant_keeps_the_clean_takes_key_count_and_error(which: str, mode: str) -> None:
    check(CLIPS, which, mode)


@pytest.mark.slow
@pytest.mark.parametrize(("which", "mode"), [case(w, m, XFAIL_ALL) for w in VARIANTS
                                             for m in ("offline", "online")])
def test_a_variant_keeps_the_clean_takes_key_count_and_error_on_every_clip(which: str,
                                                                          mode: str) -> None:
    check(clips(), which, mode)


def test_duration_defaults_in_frames_at_120_hz_follow_the_rate() -> None:
    m = load("07_05.bvh")
    at120 = simplify.Online(m.skeleton, 120.0)
    assert (at120.lookahead, at120.history, at120.hop, at120.merge, at120.max_span) == (
        60, 240, 8, 8, 480)
    at30 = simplify.Online(m.skeleton, 30.0)
    assert (at30.lookahead, at30.history, at30.hop, at30.merge, at30.max_span) == (
        15, 60, 2, 2, 120)
    mixed = simplify.Online(m.skeleton, 30.0, lookahead=60, merge=Duration.seconds(0.2))
    assert (mixed.lookahead, mixed.merge, mixed.history) == (60, 6, 240)  # numbers: frames
    with pytest.raises(UsageError, match="max_span"):
        simplify.Online(m.skeleton, 30.0, max_span=Duration.seconds(0.1))


@pytest.mark.parametrize("which", ["30 Hz", "stillness"])
def test_online_with_unbounded_lookahead_equals_offline_on_a_variant(which: str) -> None:
    m = variant("07_05.bvh", which).motion
    kf = simplify.Online(m.skeleton, m.fps, lookahead=m.n_frames)
    events = kf.push_block(m.frames()) + kf.flush()
    assert [e.frame for e in events] == simplify.extract(m).frames.tolist()


ODD_XFAIL: dict[tuple[str, str], str] = {}  # at 6 Hz: 100 Hz E ratio 1.19 (02_01)


@pytest.mark.parametrize("mode", ["offline", "online"])
@pytest.mark.parametrize("which", ODD_RATES)
def test_the_split_grid_is_in_seconds_so_90_and_100_hz_keep_the_clean_takes_keys(
        which: str, mode: str) -> None:
    # measured on a grid of frame numbers: F1 0.33-0.44 at 90 Hz, 0.42-0.44 at 100 Hz
    scores = {n: f1("simplify", mode, n, which) for n in CLIPS}
    assert min(scores.values()) >= 0.9, scores


@pytest.mark.parametrize(("which", "mode"), [case(w, m, ODD_XFAIL) for w in ODD_RATES
                                             for m in ("offline", "online")])
def test_90_and_100_hz_keep_the_clean_takes_key_count_and_error(which: str, mode: str) -> None:
    check(CLIPS, which, mode)
