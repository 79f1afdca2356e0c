"""`streamkey bench` as a user runs it: progress on stderr, files written, Ctrl-C keeps what
was measured. Real subprocesses on the shared clips; nothing here times anything."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

from cmu import DATA


def _bench(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "streamkey", "bench", "--data", str(DATA),
                             *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


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

