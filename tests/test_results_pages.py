"""docs/results.md is the rendering of the committed bench output files (results/) through
the template streamkey/bench/results.md.in: a hand edit or a page left stale by new bench
files fails here, and the template itself carries no figure."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from streamkey.bench import pages
from streamkey.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "results.md"
RESULTS = ROOT / "results"

# Digits the template may hold: citations of the papers' own tables and equations (numbers of
# a section of a thesis or a paper, not measurements).
CITATIONS = ("Table 4.1", "eq. 4.1", "eq. 4.2", "Table 2")
NAMES = ("F1",)  # the F-measure's name, not a figure
CLIP = re.compile(r"\b\d{2,3}_\d{2}\b")  # clip names (02_01, 131_03)
FENCE = re.compile(r"^```.*?^```", re.S | re.M)
CODE = re.compile(r"`[^`\n]+`")


def test_page_is_the_rendering_of_the_committed_results() -> None:
    page = pages.render(RESULTS, pages.TEMPLATE.read_text(encoding="utf-8"))
    assert PAGE.read_text(encoding="utf-8") == page, (
        "docs/results.md differs from the rendering of results/: regenerate it with "
        "`.venv/bin/python -P -m streamkey.bench.pages` (never edit it by hand)")


def test_template_holds_no_figure_of_its_own() -> None:
    text = pages.TEMPLATE.read_text(encoding="utf-8")
    text = pages.FIELD.sub("", text)
    text = FENCE.sub("", text)
    text = CODE.sub("", text)
    text = CLIP.sub("", text)
    for cited in (*CITATIONS, *NAMES):
        text = text.replace(cited, "")
    stray = [(n, line) for n, line in enumerate(text.splitlines(), 1)
             if re.search(r"[0-9]", line)]
    assert not stray, f"figures typed into the template (put them in a field): {stray}"


def test_every_field_of_the_template_is_filled_and_the_page_has_none_left() -> None:
    assert pages.FIELD.search(PAGE.read_text(encoding="utf-8")) is None
    assert "{{" not in PAGE.read_text(encoding="utf-8")


def test_a_hand_edit_is_found_by_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                       ) -> None:
    edited = tmp_path / "results.md"
    edited.write_text(PAGE.read_text(encoding="utf-8").replace("**", "", 1), encoding="utf-8")
    assert pages.main(["--results", str(RESULTS), "-o", str(edited), "--check"]) == 1
    assert "stale" in capsys.readouterr().err
    shutil.copy(PAGE, edited)
    assert pages.main(["--results", str(RESULTS), "-o", str(edited), "--check"]) == 0


def test_a_missing_bench_file_names_the_file_and_its_command(tmp_path: Path) -> None:
    shutil.copytree(RESULTS, tmp_path / "results")
    (tmp_path / "results" / "bench_latency.json").unlink()
    with pytest.raises(UsageError, match=r"bench_latency\.json: missing; write it with "
                                         r"`streamkey bench --latency -o results`"):
        pages.render(tmp_path / "results", pages.TEMPLATE.read_text(encoding="utf-8"))
