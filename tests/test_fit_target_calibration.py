"""Per-channel phase self-calibration of the range-azimuth fit target
(:mod:`sionna_mmir.fit.target_calibration`).

Truth: point targets synthesised with exact per-pair delays
(``synthesize_adc``) and planted per-channel phases; the reference render
has other target amplitudes than the capture, as an unfitted scene's
materials would.
"""
from __future__ import annotations

import numpy as np
import pytest

from sionna_mmir.fit.target_calibration import (MIN_RA_GAIN, calibrate_target,
                                                channel_phases)
from sionna_mmir.fmcw.synthesize import synthesize_adc
from sionna_mmir.radar.config import SPEED_OF_LIGHT, RadarConfig

TARGETS = np.array([[2.0, 0.9, 0.0], [3.5, -1.1, 0.1], [4.6, 0.3, -0.1]])    # radar frame [m]


def _adc(radar, gains):
    tx, rx = radar.tx_positions, radar.rx_positions
    out = 0
    for p, g in zip(TARGETS, gains):
        tau = (np.linalg.norm(p - tx, axis=1)[:, None] + np.linalg.norm(p - rx, axis=1)[None])
        a = np.full(tau.shape + (1,), g / np.linalg.norm(p) ** 2, complex)
        out = out + synthesize_adc(radar, a, tau[..., None] / SPEED_OF_LIGHT).astype(complex)
    return out


def _capture(radar, phases=None, seed=0):
    y = _adc(radar, [0.8, 1.0, 0.4])                         # the "true" materials
    if phases is not None:
        y = y * np.exp(1j * phases)[..., None, None]
    rng = np.random.default_rng(seed)
    n = 0.01 * np.abs(y).max() * (rng.normal(size=y.shape) + 1j * rng.normal(size=y.shape))
    return (y + n)[None]


@pytest.fixture(scope="module")
def radar():
    return RadarConfig.awr1843(num_chirps=2, num_samples=128)


def test_01_scrambled_phases_are_recovered_and_the_target_corrected(radar):
    planted = np.random.default_rng(3).uniform(-np.pi, np.pi, (3, 4))
    reference = _adc(radar, [1.0, 0.7, 0.5])                 # initial materials
    y = _capture(radar, planted)
    est = channel_phases(y, reference)
    err = np.angle(np.exp(1j * (est - planted)))
    err = np.angle(np.exp(1j * (err - np.angle(np.mean(np.exp(1j * err))))))   # common phase
    assert np.degrees(np.abs(err)).max() < 2.0, np.degrees(err)          # measured 0.2
    target, cal = calibrate_target(y, reference, radar)
    assert cal.applied and cal.ra_corr_calibrated - cal.ra_corr_raw >= MIN_RA_GAIN, cal
    s = cal.summary()
    assert s["applied"] and len(s["phases_deg"]) == 3 and len(s["phases_deg"][0]) == 4


def test_02_a_calibrated_capture_keeps_its_raw_target(radar):
    from sionna_mmir.compare.harness import target_ra

    reference = _adc(radar, [1.0, 0.7, 0.5])
    y = _capture(radar)
    target, cal = calibrate_target(y, reference, radar)
    assert not cal.applied, cal
    assert np.degrees(np.abs(cal.phases_rad)).max() < 2.0
    np.testing.assert_array_equal(target, target_ra(y, radar))


def test_03_mismatched_channels_are_refused_and_an_empty_model_changes_nothing(radar):
    y = _capture(radar)
    with pytest.raises(ValueError, match="does not match"):
        channel_phases(y, np.zeros((1, 4, 2, 128), complex))
    np.testing.assert_array_equal(channel_phases(y, np.zeros((3, 4, 2, 128), complex)), 0.0)
