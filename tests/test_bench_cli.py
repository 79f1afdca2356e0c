"""`streamkey bench` as a user runs it: progress on stderr, files written, Ctrl-C keeps what
was measured. Real subprocesses on the shared clips; nothing here times anything."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

from cmu import DATA


def _sigint_default() -> None:
    """In the child: Ctrl-C's default action, even when this test runs as a background job
    (whose shell ignores SIGINT for it, and Python then installs no KeyboardInterrupt)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _bench(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "streamkey", "bench", "--data", str(DATA),
                             *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_sigint_default)


def test_bench_reports_progress_and_writes_every_row(tmp_path):
    proc = _bench("--offline", "--frames", "1500", "-o", str(tmp_path))
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    for name in ("features (FK, once)", "saliency", "speed", "simplify", "decimate"):
        assert f"bench offline: {name}: seconds " in err, err
    doc = json.loads((tmp_path / "bench_offline.json").read_text())
    assert doc["frames"] == 1500 and "partial" not in doc
    assert [r["method"] for r in doc["rows"]][:3] == ["features (FK, once)", "saliency", "speed"]
    assert f"wrote {tmp_path / 'bench_offline.md'}" in out


def test_ctrl_c_writes_the_rows_measured_so_far_and_exits_130(tmp_path):
    proc = _bench("--online", "--quick", "-o", str(tmp_path))
    assert proc.stderr is not None
    lines = []
    for line in proc.stderr:  # wait on state: the first finished row
        lines.append(line)
        if line.startswith("bench online: saliency: mean_us "):
            break
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, "".join(lines) + err
    assert "Traceback" not in err and "interrupted" in err
    doc = json.loads((tmp_path / "bench_online.json").read_text())
    assert doc["partial"] is True
    assert doc["rows"][0]["method"] == "saliency" and doc["rows"][0]["mean_us"] > 0
    assert (tmp_path / "bench_online.md").exists()
    assert f"wrote {tmp_path / 'bench_online.json'}" in out



def test_perf_rows_carry_goals_streams_per_core_and_load(tmp_path):
    """`bench --perf`'s online part on a short stream: every performance target is a row with
    its goal, met flag, streams per core and the load average it was measured under (the
    numbers themselves are the bench's business, not this test's)."""
    from streamkey.bench import PERF_ONLINE_GOALS, bench_perf_offline, bench_perf_online

    online = bench_perf_online(1_500, DATA)
    targets = [row["target"] for row in online["rows"]]
    assert targets == list(PERF_ONLINE_GOALS)
    for row in online["rows"]:
        assert 0 < row["p50_us"] <= row["p99_us"] <= row["max_us"]
        assert row["streams_per_core"] > 0 and row["load_average"] >= 0
        assert isinstance(row["met"], bool) and row["goal"].startswith("mean <= ")
    offline = bench_perf_offline([500, 1_500], DATA, methods=["speed", "decimate"])
    rows = {row["target"]: row for row in offline["rows"]}
    assert set(rows) == {"features", "speed", "decimate"}
    assert all(row["s@1500"] > 0 and row["met"] is False for row in rows.values())  # < 100k


def test_latency_bench_names_each_run_before_it_starts(monkeypatch):
    """`bench --latency` is minutes of live runs: each starts with a line saying which run of
    how many and the time left (the runs themselves are the live tests' business)."""
    from streamkey.bench import live

    done: list[tuple[str, bool]] = []
    lines: list[str] = []

    def one(transport, clip, frames, realtime=False):
        done.append((transport, realtime))
        assert len(lines) == len(done)  # its line came first
        return {"transport": transport}

    monkeypatch.setattr(live, "_latency_one", one)
    live.run_live_bench("latency", DATA, True, lines.append)
    assert done == [("osc", False), ("zmq", False), ("osc", True), ("zmq", True)]
    assert lines[0].startswith("bench latency: run 1/4: osc, normal priority, 20 s of frames")
    assert lines[3].startswith("bench latency: run 4/4: zmq, SCHED_RR")
