"""ColoRadar calibration from its calib folder: measured coupling removed, phases aligned."""
import numpy as np
import pytest

from sionna_mmir import RadarConfig
from sionna_mmir.cli.commands import point_target_paths
from sionna_mmir.fmcw import synthesize_adc
from sionna_mmir.processing.coloradar_calibration import (coloradar_phase_frequency_correct,
                                                          coloradar_range_fft)


@pytest.fixture(scope="module")
def calib(measured_dir):
    d = measured_dir / "coloradar_calib"
    if not d.is_dir():
        pytest.skip(f"{d} absent")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        radar = RadarConfig.from_coloradar(d, "cascade").replace(num_chirps=2)
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


def test_02_phase_correction_is_unit_modulus_and_aligns_injected_errors(calib):
    """Channels perturbed by the file's measured phases come back aligned (far-field target)."""
    from sionna_mmir.captures.coloradar_calib import read_phase_frequency_calib

    d, radar = calib
    cal = read_phase_frequency_calib(d / "cascade" / "phase_frequency_calib.txt")
    a, tau, _ = point_target_paths(radar, [(1e4, 0.0, 0.0, 0.0)])   # far field, boresight
    clean = synthesize_adc(radar, np.ones_like(a), tau)
    err = (cal.phase / cal.phase[0, 0])
    err = err / np.abs(err)
    bins = cal.frequency_bins - cal.frequency_bins[0, 0]
    n = np.arange(radar.num_samples)
    ramp = np.exp(2j * np.pi * bins[..., None] / cal.num_samples * (radar.slope / cal.slope)
                  * (cal.sample_rate / radar.sample_rate) * n)
    dirty = clean * err[:, :, None, None] * ramp[:, :, None, :]
    fixed = coloradar_phase_frequency_correct(dirty, radar, d, interp_factor=1)
    assert np.allclose(np.abs(fixed), np.abs(dirty), rtol=1e-5)
    rel = fixed * np.conj(clean)
    rel = rel / rel[0, 0]
    assert np.degrees(np.abs(np.angle(rel))).max() < 0.5
