"""Fixtures shared by the tests."""

from __future__ import annotations

from pathlib import Path

import pytest
from cmu import DATA


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The shared CMU data folder; fails loudly (not skip) when it is missing."""
    assert DATA.is_dir(), f"shared CMU data not found at {DATA}"
    return DATA
