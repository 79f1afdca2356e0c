"""Key strengths (`keyframes.rank_strengths`): the vectorised full windows give the numbers of
the per-key definition (`rank_strength` over the key and the window - 1 keys before it)."""

from __future__ import annotations

import numpy as np
import pytest
from cmu import DATA

from streamkey.amc import read_motion
from streamkey.keyframes import STRENGTH_WINDOW, rank_strength, rank_strengths
from streamkey.methods import curvefit


def per_key(scores: np.ndarray, window: int) -> np.ndarray:
    return np.array([rank_strength(scores[max(0, i - window + 1) : i + 1], float(scores[i]))
                     for i in range(len(scores))])


@pytest.mark.numeric
@pytest.mark.parametrize("n", [0, 1, 2, 63, 64, 65, 300, 5000])
@pytest.mark.parametrize("window", [1, 2, 5, STRENGTH_WINDOW])
def test_rank_strengths_equal_the_per_key_definition(n: int, window: int) -> None:
    rng = np.random.default_rng(n + window)
    for scores in (rng.integers(0, 4, n).astype(float), rng.normal(size=n),
                   np.where(rng.random(n) < 0.2, np.nan, rng.integers(0, 3, n))):
        got = rank_strengths(scores, window)
        assert got.dtype == np.float64 and got.shape == (n,)
        np.testing.assert_array_equal(got, per_key(scores, window))


@pytest.mark.numeric
def test_rank_strengths_of_a_real_result_equal_the_per_key_definition() -> None:
    k = curvefit.extract(read_motion(DATA / "07_01.bvh"))  # scores: channels keyed per frame
    assert len(k) > 2 * STRENGTH_WINDOW
    np.testing.assert_array_equal(k.strength, per_key(k.scores, STRENGTH_WINDOW))
