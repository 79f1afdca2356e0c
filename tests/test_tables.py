"""`streamkey eval` tables: aligned E, E / E_uniform per method and clip, clips beating uniform,
and every registered offline method picked up by the table generator."""

from __future__ import annotations

import csv

import pytest
from cmu import DATA

from streamkey import tables
from streamkey.methods import OFFLINE_METHODS


def _rows(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_eval_tables_report_ratios_to_uniform_for_every_registered_method(tmp_path,
                                                                          monkeypatch):
    # a method registered under a new name (here uniform sampling again) joins the tables
    monkeypatch.setitem(OFFLINE_METHODS, "uniform_again", "baselines:uniform")
    assert "uniform_again" in tables.equal_count_methods()
    assert "uniform_again" not in tables.natural_methods()  # it needs a count
    assert tables.equal_count_methods()[-1] == "uniform"
    assert {"saliency", "simplify", "decimate"} <= set(tables.equal_count_methods())
    assert {"saliency", "speed", "simplify", "isodata", "curvefit"} <= set(
        tables.natural_methods()) and not {"uniform", "decimate"} & set(tables.natural_methods())
    clips = tmp_path / "clips"
    clips.mkdir()
    for name in ("07_01.bvh", "08_01.bvh"):
        (clips / name).symlink_to(DATA / name)
    tables.evaluate_files(sorted(clips.iterdir()), tmp_path / "out")
    out = tmp_path / "out"
    md = (out / "equal_count.md").read_text(encoding="utf-8")
    assert "not End Sites" in md and "E/E_u decimate" in md
    assert "| uniform_again | 2 | 1.000 | 1.000 | 0 of 2 |" in md
    equal = _rows(out / "equal_count.csv")
    by = {(r["clip"], r["method"]): r for r in equal}
    beats: dict[str, int] = {}
    for (clip, method), r in by.items():
        uniform = by[(clip, "uniform")]
        assert r["keyframes"] == uniform["keyframes"] == r["saliency_keyframes"]
        assert float(r["E_over_uniform"]) == pytest.approx(float(r["E"]) / float(uniform["E"]))
        beats[method] = beats.get(method, 0) + (float(r["E_over_uniform"]) < 1.0)
    natural = {(r["clip"], r["method"]): r for r in _rows(out / "natural_count.csv")}
    assert natural[("07_01.bvh", "curvefit")]["E_over_uniform"] == ""  # keys per channel
    assert float(natural[("07_01.bvh", "isodata")]["E_over_uniform"]) > 0
    summary = {(r["table"], r["method"]): r for r in _rows(out / "summary.csv")}
    for method in tables.equal_count_methods()[:-1]:
        assert int(summary[("equal", method)]["clips_beating_uniform"]) == beats[method]
    assert ("natural", "isodata") in summary and ("natural", "curvefit") not in summary
