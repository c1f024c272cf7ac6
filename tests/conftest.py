"""Shared fixtures: generated maps, and the third-party maps in ../shared/maps (skipped when absent)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

REPO = Path(__file__).resolve().parents[1]
SHARED_MAPS = Path(os.environ.get("FEAT2MAP_SHARED_MAPS", REPO.parent / "shared" / "maps"))


def shared_map(relative: str) -> Path:
    """Path of a third-party map under ../shared/maps, or skip the test with the reason."""
    path = SHARED_MAPS / relative
    if not path.exists():
        pytest.skip(f"third-party map {path} not present (../shared/maps is absent on this machine)")
    return path


@pytest.fixture(scope="session")
def sf_default_map():
    """The paper's M1-style map: the embedded San Francisco feature space, seed 1."""
    import feat2map

    return feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1)
