"""ColoRadar calibration from its calib folder: measured coupling removed, phases aligned."""
import numpy as np
import pytest

from sionna_mmir import RadarConfig
from sionna_mmir.fmcw.targets import point_target_paths
from sionna_mmir.fmcw import synthesize_adc
from sionna_mmir.captures.coloradar_calib import (coloradar_phase_frequency_correct,
                                                   coloradar_range_fft, read_coloradar_config)


@pytest.fixture(scope="module")
def calib(measured_dir):
    d = measured_dir / "coloradar_calib"
    if not d.is_dir():
        pytest.skip(f"{d} absent")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        radar = read_coloradar_config(d, "cascade").replace(num_chirps=2)
    return d, radar


def test_01_measured_coupling_is_removed_exactly(calib):
    """ADC = target + the file's own coupling (synthesised in the range domain) -> target alone."""
    from sionna_mmir.captures.coloradar_calib import read_coupling_calib
    from sionna_mmir.processing.range_fft import range_fft

    d, radar = calib
    a, tau, _ = point_target_paths(radar, [(5.0, 10.0, 0.0, 0.0)])
    target = synthesize_adc(radar, a * 1e4, tau)
    coupling = read_coupling_calib(d / "cascade" / "coupling_calib.txt")
    full = np.zeros(radar.adc_shape[:2] + (radar.num_samples,), complex)
    full[..., :coupling.shape[-1]] = coupling
    leak_adc = np.fft.ifft(full, axis=-1)[:, :, None, :]            # rect-window range FFT inverse
    spec = coloradar_range_fft(target + leak_adc, radar, d, phase_frequency=False)
    ref, _ = range_fft(target, radar, window="rect")
    assert np.abs(spec - ref).max() < 1e-3 * np.abs(ref).max()


def test_02_phase_frequency_correction_undoes_physical_channel_delays(calib, tmp_path):
    """Each channel gets an extra physical delay and phase (through synthesize_adc).

    A calibration file is written from those physical errors as a corner
    capture would record them (plain-FFT peak bin ``S dtau N / fs`` and peak
    phase ``2 pi (f0 + S t0) dtau + phi``); the correction read back from the
    folder must align the channels with the error-free capture.
    """
    import json
    import shutil

    d, radar = calib
    rng = np.random.default_rng(7)
    dtau = rng.uniform(-40e-12, 40e-12, size=(radar.num_tx, radar.num_rx))   # ~ +/- 1.2 cm
    phi = rng.uniform(-np.pi, np.pi, size=dtau.shape)
    a, tau, _ = point_target_paths(radar, [(1e4, 0.0, 0.0, 0.0)])            # far field, boresight
    clean = synthesize_adc(radar, np.ones_like(a), tau)
    dirty = synthesize_adc(radar, np.exp(1j * phi)[..., None], tau + dtau[..., None])
    f_first = radar.start_frequency + radar.slope * radar.adc_start_time
    bins = radar.slope * dtau * radar.num_samples / radar.sample_rate + 50.0
    peaks = np.exp(1j * (2 * np.pi * f_first * dtau + phi))
    cal_dir = tmp_path / "calib"
    shutil.copytree(d, cal_dir)
    doc = {"antennaCalib": {"numTx": radar.num_tx, "numRx": radar.num_rx,
                            "frequencySlope": radar.slope, "samplingRate": radar.sample_rate,
                            "frequencyCalibrationMatrix": bins.ravel().tolist(),
                            "phaseCalibrationMatrix": np.stack([peaks.real, peaks.imag], -1).ravel().tolist()}}
    (cal_dir / "cascade" / "phase_frequency_calib.txt").write_text(json.dumps(doc))
    fixed = coloradar_phase_frequency_correct(dirty, radar, cal_dir, interp_factor=1)
    assert np.allclose(np.abs(fixed), np.abs(dirty), rtol=1e-5)
    before = dirty * np.conj(clean)
    rel = fixed * np.conj(clean)
    rel = rel / rel[0, 0]
    assert np.degrees(np.abs(np.angle(before / before[0, 0]))).max() > 30   # errors were real
    assert np.degrees(np.abs(np.angle(rel))).max() < 0.5
