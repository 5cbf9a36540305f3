"""Sensor profiles, raw-capture robustness and older TI files (issue 17).

Synthetic units (known gains, delays and leakage taps) stand in for real
hardware: the calibration must recover them, carry them to another slope,
and a profile must change the forward model it is applied to.  The
detection must find a target next to an interference comb as strong as it.
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest
import scipy.io

from sionna_mmir import Capture, RadarConfig
from sionna_mmir.cli.main import EXIT_BAD_INPUT, main
from sionna_mmir.effects.profile import (FORMAT_VERSION, load_profile, new_profile, residual_db,
                                         save_profile)
from sionna_mmir.effects.sensor_calibration import calibrate_profile, leak_tap_delays
from sionna_mmir.fmcw.synthesize import synthesize_adc
from sionna_mmir.fmcw.targets import point_target_paths
from sionna_mmir.processing.detection import find_target, search_start, strongest_return
from sionna_mmir.processing.imaging import range_azimuth
from sionna_mmir.processing.virtual_array import VirtualArray

C = 299_792_458.0


def _unit(radar, seed=1):
    """A synthetic unit: channel gains, delays (tens of ps of routing, their carrier
    phase partly trimmed as on a factory-trimmed unit, so a beam still forms), leakage taps."""
    rng = np.random.default_rng(seed)
    t, r = radar.num_tx, radar.num_rx
    delay = rng.normal(0, 30e-12, (t, r))
    delay = delay - delay.mean()
    gain = (10 ** (rng.normal(0, 1.5, (t, r)) / 20)
            * np.exp(1j * np.radians(rng.normal(0, 30, (t, 1)) + rng.normal(0, 30, (1, r))))
            * np.exp(-2j * np.pi * radar.center_frequency * delay))
    taps = 2 * np.array([0.08, 0.15]) / C
    leak = (rng.normal(size=(t, r, 2)) + 1j * rng.normal(size=(t, r, 2))) * 0.5
    return gain, delay, leak, taps


def _capture(radar, unit, targets, noise=1e-3, seed=2):
    """Chirp-averaged capture of point ``targets`` (range, az deg) through ``unit``."""
    gain, delay, leak, taps = unit
    centre = VirtualArray(radar).phase_centre()
    _, tau, _ = point_target_paths(radar, [(r, az, 0.0, 0.0) for r, az in targets], origin=centre)
    f = radar.start_frequency + radar.slope * radar.sample_times()
    x = sum(np.exp(2j * np.pi * (tau[..., k] + delay)[..., None] * f) for k in range(len(targets)))
    x = gain[..., None] * x + leak @ np.exp(2j * np.pi * np.outer(taps, f))
    rng = np.random.default_rng(seed)
    x = x + noise * (rng.normal(size=x.shape) + 1j * rng.normal(size=x.shape))
    return Capture(x[:, :, None, :].astype(np.complex64), radar, {"file": "synthetic"}, "synth")


@pytest.fixture(scope="module")
def radar():
    return RadarConfig.mmwcas(num_chirps=1)


@pytest.fixture(scope="module")
def unit(radar):
    return _unit(radar)


@pytest.fixture(scope="module")
def profile(radar, unit):
    caps = [_capture(radar, unit, [(4.0, 5.0)]), _capture(radar, unit, [(6.5, -8.0)], seed=3)]
    return calibrate_profile(caps)


def _coherence(a, b, radar):
    """Phase coherence of ``a`` and ``b`` up to a plane wave (a direction is the scene's)."""
    from sionna_mmir.effects.sensor_calibration import _plane_delay, _steering

    q = a * np.conj(b)
    u = _steering(q, radar)
    q = q * np.exp(-2j * np.pi * radar.center_frequency * _plane_delay(radar, u))
    return abs(np.mean(q / np.abs(q)))


def test_calibration_recovers_the_unit(radar, unit, profile):
    gain, delay, leak, taps = unit
    h_true = gain[..., None] * np.exp(2j * np.pi * delay[..., None] * radar.start_frequency)
    h_fit = profile.channel_response(radar)[..., 0]
    assert _coherence(h_true[..., 0], h_fit, radar) > 0.99
    assert np.sqrt(np.mean((profile.delay - delay) ** 2)) < 5e-12
    f = radar.start_frequency + radar.slope * radar.sample_times()
    truth = leak @ np.exp(2j * np.pi * np.outer(taps, f))
    assert residual_db(truth, profile.leakage(radar)) < -20
    for q in profile.quality.values():
        assert q["residual_profile_db"] < -20


def test_profile_carries_to_another_slope_and_sample_rate(radar, unit, profile):
    """Delays and leakage taps map through range: a capture at half the slope and
    another sample rate is predicted by the profile calibrated at the first."""
    other = radar.replace(slope=radar.slope / 2, sample_rate=radar.sample_rate * 1.25)
    cap = _capture(other, unit, [(5.0, 12.0)], noise=0.0)
    from sionna_mmir.effects.sensor_calibration import fit_scene

    fitted = fit_scene(cap, profile)
    assert fitted["residual_db"] < -20
    assert abs(fitted["range_m"] - 5.0) < 0.05


def test_profile_round_trip(tmp_path, profile):
    path = save_profile(profile, tmp_path / "p.h5")
    back = load_profile(path)
    for k in ("gain", "delay", "leak", "leak_delays", "tx_positions", "rx_positions"):
        np.testing.assert_array_equal(getattr(back, k), getattr(profile, k))
    assert back.waveform == profile.waveform and back.sources == profile.sources
    assert back.radar == "mmwcas" and back.format_version == FORMAT_VERSION
    assert "iq_imbalance" in back.not_fitted and "channel_gain" in back.fitted
    with pytest.raises(FileExistsError):
        save_profile(profile, path)


def test_profile_changes_the_forward_model(radar, profile):
    """ProfiledModel: the inner render goes through s H x + L (Dr.Jit, frozen)."""
    import mitsuba as mi

    from sionna_mmir.fit.profiled import ProfiledModel
    from sionna_mmir.fmcw.engine import DrAdc
    from sionna_mmir.paths.render import to_numpy

    x = synthesize_adc(radar, np.ones((12, 16, 1)), np.full((12, 16, 1), 2 * 3.0 / C))

    class Inner:
        def __init__(self):
            self.radar = radar

        def latents(self):
            return {}

        def render(self, z, seed):
            return DrAdc(mi.TensorXf(x.real.astype(np.float32)),
                         mi.TensorXf(x.imag.astype(np.float32))), {}

    data = profile.apply(x, radar, 3.0)
    wrapped = ProfiledModel(Inner(), profile, data)
    assert abs(wrapped.scale - 3.0) < 1e-3
    y = to_numpy(wrapped.render({}, 0)[0])
    assert residual_db(data, y) < -60
    assert residual_db(y, x) > -1                     # not the bare render


def test_detection_rejects_a_comb_as_strong_as_the_target(radar, unit):
    """Equally spaced tones, aligned across channels, as strong as the target: the
    plain maximum locks onto the comb; find_target finds the target."""
    cap = _capture(radar, unit, [(7.3, 10.0)], noise=1e-2)
    n = np.arange(radar.num_samples)
    comb = sum(np.exp(2j * np.pi * k * n / radar.num_samples) for k in (40, 60, 80, 100))
    adc = cap.adc + 1.3 * comb                          # every channel, one phase
    ra, ranges, az = range_azimuth(adc, radar)
    naive, _, _ = strongest_return(ra, ranges, az, 1.0, radar.max_range * 0.9)
    assert min(abs(naive - ranges[k]) for k in (40, 60, 80, 100)) < 0.1
    r, a, peaks = find_target(adc, radar)
    assert abs(r - 7.3) < 0.1 and abs(np.degrees(a) - 10.0) < 3
    assert sum(p["interference"] for p in peaks) >= 3


def test_search_starts_past_the_leakage_when_bins_are_wide():
    wide = RadarConfig.mmwcas(num_chirps=1, slope=5e12)        # ~0.9 m range bins
    assert wide.range_resolution > 0.8
    assert search_start(wide, 1.0) > 0.35 + 2 * wide.range_resolution


# ----------------------------------------------------------------- command line
def _err(capsys):
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.startswith("error: ") and err.count("\n") == 1, err
    return err


@pytest.fixture(scope="module")
def files(tmp_path_factory, profile):
    import trimesh

    d = tmp_path_factory.mktemp("profiles")
    good = str(save_profile(profile, d / "good.h5"))
    v = np.array([[3.0, -.5, -.5], [3.0, .5, -.5], [3.0, .5, .5], [3.0, -.5, .5]])
    trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False).export(str(d / "wall.ply"))
    return d, good


def _edited(src, dst, edit):
    import shutil

    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        edit(f)
    return str(dst)


def _nan(f):
    g = f["gain"][()]
    g[0, 0] = np.nan
    del f["gain"]
    f["gain"] = g


@pytest.mark.parametrize("case,words", [
    ("other_radar", ("another radar",)),
    ("channels", ("channel counts",)),
    ("nan", ("gain holds NaN",)),
    ("newer", ("format version 2", "newer")),
])
def test_bad_profile_refused(capsys, files, case, words):
    d, good = files
    radar = "mmwcas"
    if case == "other_radar":
        path = _edited(good, d / "other.h5", lambda f: f.attrs.__setitem__("radar", "other"))
    elif case == "channels":
        path, radar = good, "awr1843"
    elif case == "nan":
        path = _edited(good, d / "nan.h5", _nan)
    else:
        path = _edited(good, d / "newer.h5", lambda f: f.attrs.__setitem__("format_version", 2))
    out = d / f"out_{case}.h5"
    code = main(["render", str(d / "wall.ply"), "--radar", radar, "--sensor-profile", path,
                 "--out", str(out), "--rays", "100"])
    err = _err(capsys)
    assert code == EXIT_BAD_INPUT and path in err, err
    for w in words:
        assert w in err, err
    assert not out.exists()


def test_calibrate_command(capsys, tmp_path, radar, unit):
    a = tmp_path / "a.h5"
    _capture(radar, unit, [(4.0, 5.0)]).save(a)
    out = tmp_path / "unit.h5"
    assert main(["calibrate", str(a), "--out", str(out), "--rounds", "1"]) == 0
    assert load_profile(out).sources == (str(a),)
    assert main(["calibrate", str(a), "--out", str(out)]) == EXIT_BAD_INPUT      # no overwrite
    assert "exists" in _err(capsys)


def test_old_ti_file_without_sample_rate(capsys, tmp_path):
    """An older TI calibration file lacks params.Sampling_Rate_sps: refused with a
    hint, read with --sample-rate (or a waveform config file)."""
    n = 256
    w = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(1, n + 1) / (n + 1))
    adc = np.exp(2j * np.pi * 40 * np.arange(n) / n)[:, None, None] * np.ones((1, 16, 12))
    rx_fft = np.fft.fft(adc * (w / np.sqrt(np.mean(w ** 2)))[:, None, None], 5 * n, axis=0)
    path = tmp_path / "old.mat"
    scipy.io.savemat(path, {"calibResult": {"Rx_fft": rx_fft},
                            "params": {"Slope_MHzperus": 78.986}})
    assert main(["info", str(path)]) == EXIT_BAD_INPUT
    err = _err(capsys)
    assert "Sampling_Rate_sps" in err and "--sample-rate" in err and str(path) in err
    assert main(["info", str(path), "--sample-rate", "8e6"]) == 0
    assert "fs 8.000 Msps" in capsys.readouterr().out
    cfg = tmp_path / "waveform_cfg.txt"
    cfg.write_text("adc_sample_frequency 8000000\n")
    assert main(["info", str(path), "--waveform-config", str(cfg)]) == 0
    assert main(["info", str(path), "--sample-rate", "4e6", "--slope", "60"]) == EXIT_BAD_INPUT
    assert "Slope_MHzperus" in _err(capsys)


def test_frozen_profile_in_the_effect_chain(radar, profile):
    """The loop's sensor chain with a profile: the nuisance gain alone fits a capture
    made by the profile (the profile is applied, not fitted)."""
    from sionna_mmir.effects import EffectContext, EffectModel
    from sionna_mmir.effects.profile import frozen_profile_effect

    x = synthesize_adc(radar, np.ones((12, 16, 1)), np.full((12, 16, 1), 2 * 5.0 / C))[None]
    cap = Capture(profile.apply(x, radar, 0.7 - 0.2j).astype(np.complex64), radar, {})
    chain = EffectModel(EffectContext.from_capture(cap), cap.frames, base=x)
    chain.add(frozen_profile_effect(profile, radar, chain.scale))
    assert chain.components[-1].specs == {}
    chain.fit(trainable=[], maxiter=100)
    assert residual_db(cap.frames, chain.mean_adc()) < -40


def test_calibrate_refuses_two_radars(capsys, tmp_path, radar, unit):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    _capture(radar, unit, [(4.0, 5.0)]).save(a)
    other = RadarConfig.awr1843(num_chirps=1)
    rng = np.random.default_rng(0)
    Capture((rng.normal(size=(1, *other.adc_shape)) + 0j).astype(np.complex64), other, {}).save(b)
    out = tmp_path / "p.h5"
    assert main(["calibrate", str(a), str(b), "--out", str(out)]) == EXIT_BAD_INPUT
    assert "not the same radar" in _err(capsys) and not out.exists()


def test_detection_rejects_a_comb_that_comes_and_goes(unit):
    """A comb present in some chirps only (another radar's chirps), with a phase of
    its own in every channel: comb + not persistent is interference."""
    radar = RadarConfig.mmwcas(num_chirps=8)
    one = _capture(RadarConfig.mmwcas(num_chirps=1), unit, [(5.2, -6.0)], noise=1e-2)
    adc = np.repeat(one.adc, 8, axis=2)
    rng = np.random.default_rng(4)
    n = np.arange(radar.num_samples)
    comb = sum(np.exp(2j * np.pi * k * n / radar.num_samples) for k in (50, 70, 90, 110))
    on = np.array([4.0, 0, 0, 4.0, 0, 0, 0, 4.0])[None, None, :, None]
    phase = np.exp(2j * np.pi * rng.uniform(size=(12, 16, 8, 1)))
    r, _, peaks = find_target(adc + on * phase * comb, radar)
    assert abs(r - 5.2) < 0.1
    assert all(p["transient"] for p in peaks if p["interference"])
