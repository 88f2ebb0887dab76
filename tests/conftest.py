from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENES = sorted((ROOT / "scenes").glob("*.toml"))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/plain.py


@pytest.fixture(params=[p.stem for p in SCENES])
def scene_path(request) -> Path:
    return ROOT / "scenes" / f"{request.param}.toml"
