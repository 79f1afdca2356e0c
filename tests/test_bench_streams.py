"""The scheduling model of `bench --streams` follows the engine's order."""

from __future__ import annotations

import numpy as np

from streamkey.bench.streams import simulate


def test_the_simulated_worker_puts_every_streams_due_work_before_any_re_analysis():
    ms = 1_000_000
    a = np.array([[0.1 * ms, 5 * ms, 0], [0.1 * ms, 0, 0]], dtype=np.int64)  # a re-analysis
    b = np.array([[0.1 * ms, 0, 1], [0.1 * ms, 0, 1]], dtype=np.int64)      # due events
    first, busy = simulate([a, b], due_first=True)
    old, _ = simulate([a, b], due_first=False)
    np.testing.assert_allclose(first, [0.2, 0.2])  # b's push right after a's push
    np.testing.assert_allclose(old, [5.2, 0.2])    # b's push waited for a's re-analysis
    assert busy == (0.4 + 5) * ms / (2 * 1e9 / 120)
