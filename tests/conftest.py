"""Shared test fixtures. Tests that need ../shared (real data) skip with a reason when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("AHRSD_SHARED", REPO.parent / "shared"))
BROAD_DIR = SHARED / "data" / "broad"


@pytest.fixture
def broad_dir() -> Path:
    if not BROAD_DIR.is_dir() or not any(BROAD_DIR.glob("*.npz")):
        pytest.skip(f"BROAD data not found at {BROAD_DIR} (needs ../shared/data/broad beside the checkout)")
    return BROAD_DIR
