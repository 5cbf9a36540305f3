"""Dense-frame speed (benchmark, not in the default run): one 100 x 100 frame of
mmIR and of Sionna RT on one benchmark scene, via
``comparisons/run_dense_frame_speed.py``; asserts only that both timings exist."""
from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.mark.benchmark
def test_dense_frame_speed(tmp_path):
    cmd = [sys.executable, str(ROOT / "comparisons" / "run_dense_frame_speed.py"),
           "--scenes", "parking_lot", "--out", str(tmp_path)]
    subprocess.run(cmd, check=True, cwd=ROOT)
    rows = json.loads((tmp_path / "dense_frame_speed.json").read_text())
    assert rows[0]["mmir"]["warm_frame_s"] > 0
    assert "frame_s" in rows[0]["sionna"] or "error" in rows[0]["sionna"]
