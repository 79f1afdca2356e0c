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


def test_an_external_row_measures_a_real_run_from_outside():
    """Sender, `streamkey run` and receiver as three processes over loopback: every frame
    sent is either taken in by the run or counted lost, every event is timed from its
    deciding frame's send, the run ends by itself (--idle-exit)."""
    from pathlib import Path

    from cmu import DATA

    from streamkey.bench.streams import capacity, external_row

    row = external_row(2, 1, 2.0, Path(DATA / "01_06.bvh").resolve())
    assert row["run_exit"] == 0, row["run_error"]
    assert row["frames_sent"] == 2 * 240
    assert row["frames_in"] + row["frames_lost"] == row["frames_sent"]
    assert row["events"] > 0 and 0 < row["p50_ms"] <= row["p99_ms"] <= row["max_ms"]
    assert row["met"] == (row["p99_ms"] <= 5.0 and row["max_ms"] <= 20.0
                          and row["frames_lost"] == 0)
    assert row["phases"] == "spread" and row["load_1min_before"] >= 0
    assert capacity([row], 1)["streams"] == (2 if row["met"] else 0)
    assert capacity([row], 1, "together")["streams"] == 0  # no row of that kind


def test_bench_streams_names_each_row_before_it_starts(monkeypatch):
    """`bench --streams` is many minutes of live rows: each starts with a line saying which
    row of how many, what it measures and the time left; the scheduling model says so too
    (the rows themselves are the test above's business)."""
    from cmu import DATA

    from streamkey.bench import streams

    done: list[tuple[int, int, str]] = []
    lines: list[str] = []

    def row(n, w, seconds, clip, phases="spread", python=None, realtime=False):
        done.append((n, w, phases))
        assert len(lines) == len(done)  # its line came first
        return {"streams": n, "workers": w, "phases": phases, "met": True,
                "load_1min_before": 1.0, "load_1min_after": 1.0}

    monkeypatch.setattr(streams, "external_row", row)
    monkeypatch.setattr(streams, "_simulated_rows", lambda motions, seconds: [])
    monkeypatch.setattr(streams.os, "cpu_count", lambda: 2)
    streams.bench_streams(DATA, quick=True, say=lines.append)
    assert len(done) == 16 and done[0] == (1, 1, "spread") and done[-1] == (16, 2, "together")
    assert lines[0] == ("bench streams: row 1/16: 1 stream, spread phases, 1 worker, 10 s of "
                        "frames (about 6 min left)")
    assert lines[5].startswith("bench streams: row 6/16: 4 streams, spread phases, 2 workers")
    assert lines[15].endswith("16 streams, together phases, 2 workers, 10 s of frames "
                              "(about 22 s left)")
    assert lines[16].startswith("bench streams: the scheduling model")
