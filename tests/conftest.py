"""Shared fixtures: real photographs from ../shared/data (skipped when absent), synthetic files."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = (ROOT / ".." / "shared" / "data").resolve()


def shared_dir(name: str) -> Path:
    """Folder of a real data set, or skip the test when ../shared is absent."""
    p = SHARED_DATA / name
    if not p.is_dir():
        pytest.skip(f"real data set {name} not available at {p}")
    return p


@pytest.fixture
def memorial_dir() -> Path:
    return shared_dir("memorial-debevec")


@pytest.fixture
def frobisher_dir() -> Path:
    return shared_dir("frobisher-colour-hdri")


@pytest.fixture
def crw_dir() -> Path:
    return shared_dir("raw-singles-cc0-canon-crw")
