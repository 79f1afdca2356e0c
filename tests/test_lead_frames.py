"""A sender of a whole cgspeed BVH file starts with the file's reference T-pose (and 07_12
with an all-zero dropout after it): lead frames, not captured motion. The front end drops
them from a stream and `motion.without_lead` skips them offline, so every method gets the
keys of the take streamed alone, with the noise filter on or off (real CMU clips)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from cmu import DATA

from streamkey.amc import read_motion
from streamkey.bvh import read_bvh
from streamkey.filters import RECOMMENDED_NOISE_CUTOFF_HZ, FrontEnd
from streamkey.keyframes import KeyframeEvent
from streamkey.methods import offline_method, optimal, saliency, simplify, speed
from streamkey.motion import Motion, reference_lead, without_lead
from streamkey.online import OnlineKeyframer

METHODS = ("saliency", "speed", "simplify", "optimal")
ONLINE = {"saliency": saliency.Online, "speed": speed.Online, "simplify": simplify.Online,
          "optimal": optimal.Online}


@cache
def clip(name: str) -> Motion:
    """The clip as read (first_frame past its reference frame)."""
    return read_motion(DATA / name)


@cache
def with_lead(name: str) -> Motion:
    """The same file with every frame streamed, the reference T-pose first."""
    m = clip(name)
    assert m.first_frame >= 1, name
    return Motion(m.skeleton, m.channels, m.fps, 0, m.name + "+lead")


def online_frames(m: Motion, method: str, cutoff: float | None,
                  lookahead: int | None = None) -> list[int]:
    kw = {} if lookahead is None else {"lookahead": lookahead}
    kf: OnlineKeyframer = ONLINE[method](m.skeleton, m.fps, **kw)
    kf.features.configure(cutoff)  # type: ignore[attr-defined]
    events = kf.push_block(m.frames()) + kf.flush()
    return [e.frame for e in events if isinstance(e, KeyframeEvent)]


def offline_frames(m: Motion, method: str, cutoff: float | None) -> list[int]:
    return [int(f) for f in offline_method(method)(m, noise_cutoff_hz=cutoff).frames]


@pytest.mark.parametrize("cutoff", [RECOMMENDED_NOISE_CUTOFF_HZ, None], ids=["filter", "raw"])
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", ["07_05.bvh", "02_01.bvh"])
def test_a_reference_frame_streamed_first_changes_no_key(name: str, method: str,
                                                         cutoff: float | None) -> None:
    m, lead = clip(name), with_lead(name)
    assert offline_frames(lead, method, cutoff) == offline_frames(m, method, cutoff)
    assert online_frames(lead, method, cutoff) == online_frames(m, method, cutoff)


@pytest.mark.parametrize("method", METHODS)
def test_online_equals_offline_at_unbounded_lookahead_with_the_lead(method: str) -> None:
    lead = with_lead("07_05.bvh")
    want = offline_frames(lead, method, RECOMMENDED_NOISE_CUTOFF_HZ)
    got = online_frames(lead, method, RECOMMENDED_NOISE_CUTOFF_HZ, lead.n_frames + 1)
    assert got == want and len(want) > 1


def test_the_front_end_drops_the_lead_whole_or_frame_by_frame() -> None:
    """The take's rows are the bits of the take pushed alone, the lead counted; a block,
    frame by frame or a snapshot in between give the same rows."""
    import pickle

    lead = with_lead("07_05.bvh")
    n = 200
    seq = np.arange(n, dtype=np.int64)
    time = seq / lead.fps
    chans = lead.channels[:n]

    alone = FrontEnd(lead.skeleton, lead.fps)
    want = alone.push(seq[1:], time[1:], chans[1:]).channels
    for step in (n, 1, 7):
        front = FrontEnd(lead.skeleton, lead.fps)
        got = []
        for lo in range(0, n, step):
            if lo == 3:
                front = pickle.loads(pickle.dumps(front))
            got.append(front.push(seq[lo : lo + step], time[lo : lo + step],
                                  chans[lo : lo + step]).channels)
        assert front.leads == 1
        assert np.array_equal(np.concatenate(got), want)


def test_a_dropout_after_the_reference_frame_is_a_lead_too() -> None:
    """07_12's file: the reference T-pose, then an all-zero frame, then the take."""
    m = read_bvh(DATA / "07_12.bvh")
    assert m.first_frame == 2 and not np.any(m.channels[1])
    lead = Motion(m.skeleton, m.channels, m.fps, 0, m.name)
    assert without_lead(lead).first_frame == 2
    front = FrontEnd(m.skeleton, m.fps)
    rows = front.push(np.arange(40), np.arange(40) / m.fps, m.channels[:40])
    assert front.leads == 2 and rows.seq[0] == 2


def test_captured_frames_are_no_lead() -> None:
    """No captured frame of a shared clip looks like a lead to the frame after it: a stream
    starting anywhere in a take keeps its first frame."""
    for name in ("07_05.bvh", "02_01.bvh", "05_11.amc", "16_11.bvh"):
        m = clip(name)
        c = m.channels
        assert not any(reference_lead(m.skeleton, c[i], c[i + 1])
                       for i in range(m.first_frame, m.n_frames - 1)), name
        assert without_lead(m) is m


def test_a_one_frame_stream_keeps_its_frame_and_a_window_after_a_gap_is_checked_again(
) -> None:
    m = clip("07_05.bvh")
    t = np.zeros(1)
    for cutoff in (RECOMMENDED_NOISE_CUTOFF_HZ, None):
        front = FrontEnd(m.skeleton, m.fps, cutoff)
        assert len(front.push(np.array([5]), t, m.channels[5:6])) == 0  # held: a lead?
        assert front.drain().seq.tolist() == [5]
        front.restart()  # after a long gap: the reference frame again, then the take
        chans = np.concatenate([m.channels[:1], m.channels[1:40]])
        rows = front.push(np.arange(100, 140), np.zeros(40), chans)
        rows_all = np.concatenate([rows.seq, front.drain().seq])
        assert front.leads == 1 and rows_all.tolist() == list(range(101, 140))
