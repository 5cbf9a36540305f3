"""ColoRadar calibration folder and raw frame readers."""
from __future__ import annotations

import json
import os
import shutil
import warnings

import numpy as np
import pytest

from conftest import measured_file
from sionna_mmir.captures import (PhaseFrequencyCalib, load_capture, read_coloradar_config,
                                  read_coloradar_frame, read_coloradar_run, read_coupling_calib,
                                  read_phase_frequency_calib)
from sionna_mmir.captures.coloradar_calib import (ColoRadarRepairWarning, read_heatmap_cfg,
                                                  read_transform)
from sionna_mmir.errors import CaptureFormatError, ConfigError
from sionna_mmir.radar import RadarConfig, layouts

C0 = 299_792_458.0


@pytest.fixture(scope="module")
def calib(measured_dir):
    return measured_file(measured_dir, "coloradar_calib")


def _cascade(calib, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ColoRadarRepairWarning)
        return read_coloradar_config(calib, "cascade", **kw)


def _table(path):
    """The antenna table, parsed here independently: {'tx': {i: (x, y)}, 'rx': {...}}."""
    out = {"tx": {}, "rx": {}}
    for line in path.read_text().splitlines():
        f = line.split()
        if f and f[0] in out:
            out[f[0]][int(f[1])] = (float(f[2]), float(f[3]))
    return out


def _copy_calib(calib, tmp_path):
    dst = tmp_path / "calib"
    shutil.copytree(calib, dst)
    for p in dst.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    dst.chmod(0o755)
    return dst


# ----------------------------------------------------------------- configs
@pytest.mark.measured
def test_01_cascade_config_repaired(calib):
    with pytest.warns(ColoRadarRepairWarning, match="adc_start_time"):
        r = read_coloradar_config(calib, "cascade")
    assert (r.num_tx, r.num_rx, r.num_samples, r.num_chirps) == (12, 16, 256, 16)
    assert r.slope == pytest.approx(79e12, rel=1e-6)
    assert r.sample_rate == 8e6
    assert r.start_frequency == pytest.approx(77e9, rel=1e-8)
    assert r.adc_start_time == pytest.approx(6e-6, rel=1e-9)
    assert r.ramp_end_time == pytest.approx(40e-6, rel=1e-6)
    assert r.adc_start_time + r.num_samples / r.sample_rate <= r.ramp_end_time
    assert r.tdm_order == tuple(range(12))
    assert len(r.notes) == 2
    # the same through the function the RadarConfig classmethod calls
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ColoRadarRepairWarning)
        assert read_coloradar_config(calib, "cascade", num_chirps=1) == r.replace(
            num_chirps=1)


@pytest.mark.measured
def test_02_single_chip_config(calib):
    with warnings.catch_warnings():
        warnings.simplefilter("error", ColoRadarRepairWarning)     # nothing to repair here
        r = read_coloradar_config(calib, "single_chip")
    assert (r.num_tx, r.num_rx) == (3, 4)
    assert r.num_samples == 128 and r.num_chirps == 128
    assert r.adc_start_time + r.num_samples / r.sample_rate <= r.ramp_end_time


@pytest.mark.measured
def test_03_cascade_virtual_array(calib):
    t = _table(calib / "cascade" / "antenna_cfg.txt")
    virt = {(tx[0] + rx[0], tx[1] + rx[1]) for tx in t["tx"].values() for rx in t["rx"].values()}
    az0 = sorted(a for a, e in virt if e == 0)
    assert len(az0) == 86 and az0 == list(range(86))
    r = _cascade(calib)
    g = r.virtual_grid()                                 # [tx, rx, (az, el)] in lambda/2 @ 76.8 GHz
    assert np.allclose(g, np.round(g), atol=1e-9)
    on_axis = {int(round(a)) for a, e in g.reshape(-1, 2) if abs(e) < 1e-9}
    assert len(on_axis) == 86
    # X -> +y (azimuth), Y -> +z (elevation), metres at F_design 76.8 GHz
    hw = C0 / (2 * 76.8e9)
    for i, (x, y) in t["tx"].items():
        np.testing.assert_allclose(r.tx_positions[i], [0.0, x * hw, y * hw], atol=1e-12)


@pytest.mark.measured
def test_04_cascade_table_is_mmwcas_reindexed(calib):
    """README: the TI module's array appears, re-indexed, in antenna_cfg.txt."""
    t = _table(calib / "cascade" / "antenna_cfg.txt")
    assert sorted(t["tx"].values()) == sorted(tuple(map(float, v)) for v in layouts.MMWCAS_TX)
    assert sorted(t["rx"].values()) == sorted(tuple(map(float, v)) for v in layouts.MMWCAS_RX)


# --------------------------------------------------------------- coupling
@pytest.mark.measured
def test_05_coupling_calib(calib):
    c = read_coupling_calib(calib / "cascade" / "coupling_calib.txt")
    assert c.shape == (12, 16, 128) and c.dtype == np.complex128
    s = read_coupling_calib(calib / "single_chip" / "coupling_calib.txt")
    assert s.shape == (3, 4, 64)
    text = (calib / "cascade" / "coupling_calib.txt").read_text()
    first = [float(v) for v in text.split("data:")[1].split(",")[:4]]
    assert c[0, 0, 0] == complex(first[0], first[1]) and c[0, 0, 1] == complex(first[2], first[3])
    # range bin fastest: every channel's leakage lives in the first bins
    p = np.abs(c) ** 2
    assert np.all(p[..., :4].sum(-1) > 10 * p[..., 64:].sum(-1))
    # tx-major: leakage is strongest between the Tx and Rx of one chip.  Chips from the
    # table: file Tx 3k..3k+2 and file Rx 4k..4k+3 are the same AWR2243 (device groups).
    lk = p[..., :6].sum(-1)
    chip = np.zeros((12, 16), bool)
    for k in range(4):
        chip[3 * k:3 * k + 3, 4 * k:4 * k + 4] = True
    same, other = lk[chip].mean(), lk[~chip].mean()
    assert 10 * np.log10(same / other) > 6.0
    lk_rx_major = np.abs(c.reshape(-1, 128)[:, :6]).__pow__(2).sum(-1).reshape(16, 12).T
    assert lk_rx_major[chip].mean() / lk_rx_major[~chip].mean() < same / other / 3


# ---------------------------------------------------------- phase/frequency
@pytest.mark.measured
def test_06_phase_frequency_calib(calib):
    path = calib / "cascade" / "phase_frequency_calib.txt"
    pf = read_phase_frequency_calib(path)
    assert isinstance(pf, PhaseFrequencyCalib)
    assert pf.frequency_bins.shape == (12, 16) and pf.phase.shape == (12, 16)
    assert pf.phase.dtype == np.complex128
    assert pf.slope == pytest.approx(79e12, rel=1e-6) and pf.sample_rate == 8e6
    assert pf.interp_factor == 5 and pf.num_samples == 256
    raw = json.loads(path.read_text())["antennaCalib"]
    assert pf.phase[0, 1] == complex(*raw["phaseCalibrationMatrix"][2:4])
    assert pf.frequency_bins[1, 0] == raw["frequencyCalibrationMatrix"][16]
    # tx-major: bins follow an additive tx + rx model far better than rx-major
    def resid(m):
        r = m - m.mean(1, keepdims=True) - m.mean(0, keepdims=True) + m.mean()
        return np.sqrt(np.mean(r ** 2))
    fb = np.asarray(raw["frequencyCalibrationMatrix"])
    assert resid(fb.reshape(12, 16)) < 0.6 * resid(fb.reshape(16, 12).T)
    # unit-modulus phase correction, reference channel 1
    pc = pf.phase_correction()
    assert np.allclose(np.abs(pc), 1.0) and pc[0, 0] == pytest.approx(1.0)
    # README: the calibration corner stood at about 3 m.  Bins of the plain N-point FFT
    # (interp 1) give that; read as 5x-interpolated bins they would give ~0.6 m.
    assert pf.corner_range(1).mean() == pytest.approx(3.0, abs=0.2)
    assert pf.corner_range().mean() == pytest.approx(0.6, abs=0.05)


@pytest.mark.measured
def test_07_heatmap_and_transforms(calib):
    h = read_heatmap_cfg(calib / "cascade" / "heatmap_cfg.txt")
    assert h["azimuth_bins"].size == h["num_azimuth_bins"] == 128
    assert h["elevation_bins"].size == h["num_elevation_bins"] == 32
    r = _cascade(calib)
    # ColoRadar's range bins are those of the plain N-point FFT: c fs / (2 S N)
    assert h["range_bin_width"] == pytest.approx(C0 * 8e6 / (2 * 79e12 * 256), rel=1e-3)
    assert h["range_bin_width"] == pytest.approx(r.range_resolution, rel=1e-3)
    t, q = read_transform(calib / "transforms" / "base_to_cascade.txt")
    assert t.shape == (3,) and q.shape == (4,)
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-3)


# -------------------------------------------------------------- raw frames
def _write_frame(path, adc):
    iq = np.stack([adc.real, adc.imag], axis=-1).astype("<i2")     # [tx][rx][chirp][sample][iq]
    iq.tofile(path)


@pytest.mark.measured
def test_08_synthetic_frame_round_trip(calib, tmp_path):
    radar = _cascade(calib, num_chirps=2)
    rng = np.random.default_rng(3)
    adc = (rng.integers(-30000, 30000, radar.adc_shape)
           + 1j * rng.integers(-30000, 30000, radar.adc_shape))
    path = tmp_path / "frame_7.bin"
    _write_frame(path, adc)
    cap = read_coloradar_frame(path, radar)
    assert cap.frames.shape == (1,) + radar.adc_shape
    assert np.array_equal(cap.adc, adc.astype(np.complex64))
    assert cap.metadata["frame_index"] == 7


@pytest.mark.measured
def test_09_run_folder_and_loader(calib, tmp_path):
    root = tmp_path / "dataset"
    (root / "run0" / "cascade" / "adc_samples" / "data").mkdir(parents=True)
    os.symlink(calib, root / "calib")
    radar = _cascade(calib)
    rng = np.random.default_rng(4)
    adc = rng.integers(-99, 99, radar.adc_shape) + 1j * rng.integers(-99, 99, radar.adc_shape)
    data = root / "run0" / "cascade" / "adc_samples" / "data"
    _write_frame(data / "frame_3.bin", adc)
    (root / "run0" / "cascade" / "adc_samples" / "timestamps.txt").write_text(
        "\n".join(f"{100 + 0.1 * i:.3f}" for i in range(5)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ColoRadarRepairWarning)
        cap = read_coloradar_run(root / "run0", frame=3)
        assert np.array_equal(cap.adc, adc.astype(np.complex64))
        assert cap.metadata["timestamp"] == pytest.approx(100.3)
        assert cap.metadata["frame_period"] == pytest.approx(0.1)
        via_dir = load_capture(root / "run0", frame=3)
        via_file = load_capture(data / "frame_3.bin")
    assert np.array_equal(via_dir.adc, cap.adc) and np.array_equal(via_file.adc, cap.adc)
    given = load_capture(root / "run0", frame=3, radar=radar.replace(name="mine"))
    assert given.radar.name == "mine" and np.array_equal(given.adc, cap.adc)
    assert np.array_equal(load_capture(data / "frame_3.bin", frame=3, radar=radar).adc, cap.adc)
    with pytest.raises(FileNotFoundError, match="frame_4.bin"):
        read_coloradar_run(root / "run0", frame=4)


def test_10_run_without_calib(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "frame_0.bin").write_bytes(b"\0" * 16)
    with pytest.raises(ConfigError, match="calib") as e:
        read_coloradar_run(run, frame=0)
    assert str(run) in str(e.value)
    with pytest.raises(ConfigError, match="calib_dir or radar"):
        load_capture(run / "frame_0.bin")


# ------------------------------------------------------------------ errors
@pytest.mark.measured
def test_11_config_errors(calib, tmp_path):
    cal = _copy_calib(calib, tmp_path)
    wf = cal / "cascade" / "waveform_cfg.txt"
    good = wf.read_text()

    wf.write_text(good.replace("frequency_slope", "#frequency_slope"))
    with pytest.raises(ConfigError, match="frequency_slope") as e:
        read_coloradar_config(cal, "cascade")
    assert str(wf) in str(e.value) and "missing" in str(e.value)

    wf.write_text(good + "tx_power 12\n")
    with pytest.raises(ConfigError, match="unknown key 'tx_power'") as e:
        read_coloradar_config(cal, "cascade")
    assert f"{wf}:{len(good.splitlines()) + 1}" in str(e.value)

    wf.write_text(good.replace("idle_time 4.99999987369e-06", "idle_time 5e-6 us"))
    with pytest.raises(ConfigError, match="malformed") as e:
        read_coloradar_config(cal, "cascade")
    assert f"{wf}:7" in str(e.value)

    wf.write_text(good.replace("adc_start_time 6.0", "adc_start_time six"))
    with pytest.raises(ConfigError, match="adc_start_time"):
        read_coloradar_config(cal, "cascade")

    wf.write_text(good.replace("ramp_end_time 3.99999998402e-11", "ramp_end_time 2e-11"))
    with pytest.raises(ConfigError, match="ramp_end_time") as e:
        read_coloradar_config(cal, "cascade")
    assert str(wf) in str(e.value)

    wf.write_text(good)
    with pytest.raises(ConfigError, match="'cascade', 'single_chip'"):
        read_coloradar_config(cal, "triple_chip")

    ant = cal / "single_chip" / "antenna_cfg.txt"
    ant.write_text(ant.read_text().replace("tx 1 4 0", "tx 1 4"))
    with pytest.raises(ConfigError, match="malformed") as e:
        read_coloradar_config(cal, "single_chip")
    assert str(ant) in str(e.value)


@pytest.mark.measured
def test_12_calib_file_errors(calib, tmp_path):
    cal = _copy_calib(calib, tmp_path)
    cp = cal / "single_chip" / "coupling_calib.txt"
    text = cp.read_text()
    cp.write_text(text.rstrip().rsplit(",", 2)[0] + "\n")          # drop one (re, im) pair
    with pytest.raises(CaptureFormatError, match="1534 numbers .* expected 1536") as e:
        read_coupling_calib(cp)
    assert str(cp) in str(e.value)
    cp.write_text(text.replace("num_range_bins:64\n", ""))
    with pytest.raises(ConfigError, match="num_range_bins"):
        read_coupling_calib(cp)
    pf = cal / "cascade" / "phase_frequency_calib.txt"
    doc = json.loads(pf.read_text())
    doc["antennaCalib"]["frequencyCalibrationMatrix"] = doc["antennaCalib"][
        "frequencyCalibrationMatrix"][:-1]
    pf.write_text(json.dumps(doc))
    with pytest.raises(ConfigError, match="191 values, expected numTx x numRx = 192") as e:
        read_phase_frequency_calib(pf)
    assert str(pf) in str(e.value)
    pf.write_text("{not json")
    with pytest.raises(ConfigError, match="JSON"):
        read_phase_frequency_calib(pf)


@pytest.mark.measured
def test_13_mis_sized_frame(calib, tmp_path):
    radar = _cascade(calib)
    path = tmp_path / "frame_0.bin"
    path.write_bytes(b"\0" * (4 * int(np.prod(radar.adc_shape)) - 4))
    with pytest.raises(CaptureFormatError, match="expected 3145728 bytes") as e:
        read_coloradar_frame(path, radar)
    assert str(path) in str(e.value)
