"""The documentation site (mkdocs.yml) builds with --strict, as CI builds it: every docs/ page
is in the nav and rendered, no link or anchor is broken, and the API page carries the
reference generated from the docstrings."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from cmu import ROOT

if os.environ.get("CI") != "true":  # on CI (.ci/run installs the docs extra) a missing one fails
    pytest.importorskip("mkdocs", reason="the docs extra (pip install -e '.[docs]')")


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run([sys.executable, "-P", "-m", "mkdocs", "build", "--strict",
                           "--site-dir", str(out)], cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stderr[-3000:]
    assert "WARNING" not in done.stderr, done.stderr[-3000:]
    return out


@pytest.mark.slow
def test_every_docs_page_is_in_the_nav_and_built(site: Path) -> None:
    config = (ROOT / "mkdocs.yml").read_text()
    for page in sorted((ROOT / "docs").glob("*.md")):
        assert re.search(rf":\s+{re.escape(page.name)}\s*$", config, re.M), page.name
        built = site / ("index.html" if page.stem == "index" else f"{page.stem}/index.html")
        assert built.exists(), built
    results = (site / "results" / "index.html").read_text()
    assert "Results on the shared CMU clips" in results


@pytest.mark.slow
def test_the_api_page_has_the_reference_generated_from_docstrings(site: Path) -> None:
    api = (site / "api" / "index.html").read_text()
    assert "The public API" in api  # the prose is kept
    for name in ("streamkey.amc.read_motion", "streamkey.batch.extract_motion",
                 "streamkey.online.Pipeline", "streamkey.online.Pipeline.push",
                 "streamkey.methods.speed_online.Online", "streamkey.engine.EngineConfig",
                 "streamkey.keyframes.KeyframeEvent", "streamkey.live.run_live"):
        assert f'id="{name}"' in api, name
    # a docstring's own words, so the reference is not a list of bare signatures
    assert "Wire a source to keyframers and sinks" in api
