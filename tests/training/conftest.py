"""Shared pytest fixtures for tests/training (others may add theirs here)."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))


@pytest.fixture(scope="session")
def features_cli() -> Path:
    """Path of the built dance-features CLI; skips the test with a clear message if it is not built."""
    from training.features.extract import FeatureToolMissing, find_cli

    try:
        return find_cli()
    except FeatureToolMissing as e:
        pytest.skip(f"dance-features is not built: {e}")


@pytest.fixture(scope="session")
def shared_data_dir() -> Path:
    """../shared/data (the project's sibling); skips if absent."""
    d = Path(os.environ.get("DANCE_SHARED_DATA", REPO_ROOT.parent / "shared" / "data"))
    if not d.is_dir():
        pytest.skip(f"shared data not found at {d}")
    return d
