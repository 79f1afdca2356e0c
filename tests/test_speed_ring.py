"""The ring window of the online keyframers (`streamkey.methods.ring.RingWindow`): the last
`capacity` frames, oldest first, contiguous, and small when pickled."""

from __future__ import annotations

import pickle

import numpy as np

from streamkey.methods.ring import RingWindow


def test_the_window_holds_the_newest_frames_in_order() -> None:
    ring = RingWindow(5, 2)
    assert len(ring) == 0
    seen = 0
    for block in (3, 1, 4, 7, 2):
        seqs = np.arange(seen, seen + block)
        ring.extend(seen + 10, np.stack([seqs, -seqs], axis=1).astype(float), seqs / 120.0)
        seen += block
    assert len(ring) == 5
    assert ring.first_seq == 10 + seen - 5
    assert np.array_equal(ring.rows()[:, 0], np.arange(seen - 5, seen))
    assert np.array_equal(ring.times(), np.arange(seen - 5, seen) / 120.0)
    assert ring.time(ring.first_seq + 4) == (seen - 1) / 120.0
    assert ring.dropped_since == seen - 5


def test_a_pickled_window_carries_only_its_held_rows() -> None:
    ring = RingWindow(1000, 48)
    for i in range(40):
        ring.extend(i * 30, np.full((30, 48), float(i)), np.arange(30.0))
    copy = pickle.loads(pickle.dumps(ring))
    assert np.array_equal(copy.rows(), ring.rows())
    assert copy._rows.shape == (1000, 48)  # the spare half of the buffer is not pickled
    copy.extend(copy.first_seq + len(copy), np.ones((1, 48)), np.zeros(1))
    assert len(copy) == 1000 and copy.rows()[-1, 0] == 1.0


def test_clearing_forgets_the_frames() -> None:
    ring = RingWindow(4, 1)
    ring.extend(7, np.ones((3, 1)), np.zeros(3))
    ring.clear()
    assert len(ring) == 0 and ring.dropped_since == 0
    ring.extend(50, np.zeros((1, 1)), np.zeros(1))
    assert ring.first_seq == 50
