"""``sionna-mmir residual``: the loop end to end, and every bad input."""
from __future__ import annotations

import json
import os

import h5py
import numpy as np
import pytest

from sionna_mmir.captures.capture import Capture
from sionna_mmir.cli.main import main
from sionna_mmir.fmcw.synthesize import synthesize_adc
from sionna_mmir.radar.config import RadarConfig

C = 299_792_458.0


def _pair(tmp_path, frames=1, gains=True, seed=0):
    radar = RadarConfig.awr1843(num_chirps=2)
    clean = synthesize_adc(radar, np.array([1.0, 0.3j]), 2 * np.array([2.4, 5.1]) / C)
    clean = np.broadcast_to(clean, (frames,) + clean.shape).astype(np.complex64)
    rng = np.random.default_rng(seed)
    meas = clean.copy()
    if gains:
        T, R = radar.num_tx, radar.num_rx
        g = np.exp(rng.normal(0, 0.2, T)[:, None] + rng.normal(0, 0.2, R)[None]
                   + 1j * (rng.uniform(-3, 3, T)[:, None] + rng.uniform(-3, 3, R)[None]))
        meas = meas * g[None, :, :, None, None]
    meas = meas + 0.03 * (rng.normal(size=meas.shape) + 1j * rng.normal(size=meas.shape))
    cap = str(tmp_path / "capture.h5")
    mod = str(tmp_path / "model.h5")
    Capture(frames=meas.astype(np.complex64), radar=radar).save(cap)
    Capture(frames=clean, radar=radar).save(mod)
    return cap, mod, radar


def test_01_loop_adopts_the_true_effect_and_reports_before_after(tmp_path, capsys):
    cap, mod, _ = _pair(tmp_path)
    out = str(tmp_path / "rep")
    rc = main(["residual", cap, "--model", mod, "--out", out,
               "--effects", "channel_gain,dc_offset"])
    assert rc == 0
    doc = json.load(open(os.path.join(out, "residual.json")))
    assert [a["name"] for a in doc["adoptions"]] == ["channel_gain"]
    a = doc["adoptions"][0]
    assert a["after"]["residual_energy_db"] < a["before"]["residual_energy_db"] - 10
    assert a["after"]["ra_correlation"] > a["before"]["ra_correlation"]
    assert a["candidates"][0]["name"] == "channel_gain"
    for f in ("residual.md", "ra_first_final.png", "range_profile.png", "channels.png",
              "adopt_1_channel_gain.png"):
        assert os.path.getsize(os.path.join(out, f)) > 0
    assert not os.path.exists(out + ".partial")


def test_02_existing_report_is_never_overwritten_silently(tmp_path, capsys):
    cap, mod, _ = _pair(tmp_path)
    out = tmp_path / "rep"
    out.mkdir()
    (out / "keep.txt").write_text("old")
    rc = main(["residual", cap, "--model", mod, "--out", str(out), "--effects", "dc_offset"])
    assert rc == 2
    assert f"{out}: exists; pass --overwrite" in capsys.readouterr().err
    assert (out / "keep.txt").read_text() == "old"


def test_03_model_for_another_radar_is_refused(tmp_path, capsys):
    cap, _, radar = _pair(tmp_path)
    other = RadarConfig.awr1843(num_chirps=2, slope=radar.slope * 0.5)
    mod = str(tmp_path / "other.h5")
    Capture(frames=np.ones((1,) + other.adc_shape, np.complex64), radar=other).save(mod)
    out = str(tmp_path / "rep")
    rc = main(["residual", cap, "--model", mod, "--out", out])
    assert rc == 2
    assert "different radar" in capsys.readouterr().err
    assert not os.path.exists(out) and not os.path.exists(out + ".partial")


def test_04_nan_in_the_capture_is_refused(tmp_path, capsys):
    cap, mod, _ = _pair(tmp_path)
    with h5py.File(cap, "r+") as f:
        x = f["adc"][...]
        x[0, 0, 0, 0, 3] = np.nan
        f["adc"][...] = x
    out = str(tmp_path / "rep")
    assert main(["residual", cap, "--model", mod, "--out", out]) == 2
    assert "NaN" in capsys.readouterr().err
    assert not os.path.exists(out)


def test_05_empty_residual_is_refused(tmp_path, capsys):
    cap, _, _ = _pair(tmp_path)
    out = str(tmp_path / "rep")
    assert main(["residual", cap, "--model", cap, "--out", out, "--effects", "dc_offset"]) == 2
    assert "empty residual" in capsys.readouterr().err
    assert not os.path.exists(out) and not os.path.exists(out + ".partial")


def test_06_unknown_effect_static_on_one_frame_zero_model(tmp_path, capsys):
    cap, mod, radar = _pair(tmp_path)
    out = str(tmp_path / "rep")
    assert main(["residual", cap, "--model", mod, "--out", out, "--effects", "gremlins"]) == 2
    assert "gremlins" in capsys.readouterr().err
    assert main(["residual", cap, "--model", "static", "--out", out]) == 2
    assert "multi-frame" in capsys.readouterr().err
    zero = str(tmp_path / "zero.h5")
    Capture(frames=np.zeros((1,) + radar.adc_shape, np.complex64), radar=radar).save(zero)
    assert main(["residual", cap, "--model", zero, "--out", out]) == 2
    assert "all zeros" in capsys.readouterr().err
    assert main(["residual", str(tmp_path / "missing.h5"), "--model", mod, "--out", out]) == 2
    assert not os.path.exists(out)


def test_07_bad_frame_range_and_folds(tmp_path, capsys):
    cap, mod, _ = _pair(tmp_path, frames=3)
    out = str(tmp_path / "rep")
    assert main(["residual", cap, "--model", "static", "--out", out, "--frames", "2:9"]) == 2
    assert "--frames" in capsys.readouterr().err
    assert main(["residual", cap, "--model", mod, "--out", out, "--folds", "1"]) == 2
    assert "--folds" in capsys.readouterr().err
