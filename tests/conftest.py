"""Shared fixtures: where the measured data lives, temporary output folders."""
from __future__ import annotations

import os
import pathlib

import pytest

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
MEASURED_DIR = pathlib.Path(os.environ.get(
    "SIONNA_MMIR_MEASURED", REPO_ROOT.parent / "shared" / "data" / "measured"))


@pytest.fixture(scope="module")
def measured_dir() -> pathlib.Path:
    """``../shared/data/measured`` beside the checkout; skips when absent."""
    if not MEASURED_DIR.is_dir():
        pytest.skip(f"measured data not found at {MEASURED_DIR} "
                    "(set SIONNA_MMIR_MEASURED or place it beside the checkout)")
    return MEASURED_DIR


def measured_file(measured_dir: pathlib.Path, rel: str) -> pathlib.Path:
    p = measured_dir / rel
    if not p.exists():
        pytest.skip(f"measured file {p} is absent")
    return p
