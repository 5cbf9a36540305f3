"""Point targets through the FFT imaging chain, checked against physics.

Targets are synthesised with ``sionna_mmir.fmcw.synthesize_adc`` from exact
per-pair delays (``tests/helpers.py``); expected ranges, angles, resolutions
and velocities are computed by hand from the waveform, never from the code
under test.  Angles are defined from the aperture's mean two-way phase
centre (``(tx + rx) / 2``) so that parallax of the few-cm aperture does not
bias the comparison at a few metres.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from helpers import C, direct_adc, peak_index, point_target_delays, target_at
from sionna_mmir.errors import ConfigError, InputValueError
from sionna_mmir.fmcw import synthesize_adc
from sionna_mmir.processing import (VirtualArray, doppler_fft, get_window, range_azimuth,
                                    range_azimuth_elevation, range_doppler, range_fft)
from sionna_mmir.radar.config import RadarConfig

DEG = math.pi / 180.0


def _adc(radar, xyz, amp=1.0, velocity=None):
    tau = point_target_delays(radar, xyz)
    a = np.full(tau.shape, amp, dtype=np.complex128)
    rate = None if velocity is None else np.full(tau.shape, 2.0 * velocity / C)
    return synthesize_adc(radar, a, tau, rate)


def _phase_spread_deg(ratio):
    """max - min of the phases of ``ratio`` around their circular mean [deg]."""
    ratio = np.asarray(ratio).ravel()
    d = np.angle(ratio * np.conj(np.mean(ratio / np.abs(ratio))))
    return float(np.rad2deg(d.max() - d.min()))


# --------------------------------------------------------------------------- 01
def test_01_range_resolution_and_max_range_by_hand():
    # Cascade: S = 78.986 MHz/us, 256 samples at 8 Msps.
    #   B = 78.986e12 * 256 / 8e6 = 2.52755 GHz,  dr = c / 2B = 5.9305 cm
    #   max range = fs c / 2S = 8e6 * 299792458 / (2 * 78.986e12) = 15.1821 m
    casc = RadarConfig.mmwcas()
    _, ranges = range_fft(np.zeros(casc.adc_shape, np.complex64), casc)
    assert ranges.shape == (256,)
    assert ranges[0] == 0.0
    assert abs((ranges[1] - ranges[0]) - 0.059305) < 2e-6
    assert abs(ranges[-1] + (ranges[1] - ranges[0]) - 15.1821) < 1e-3
    # AWR1843: S = 64.598 MHz/us, 128 samples at 2.5 Msps.
    #   B = 3.30742 GHz, dr = 4.5321 cm, max range = 5.8010 m
    awr = RadarConfig.awr1843()
    _, ranges = range_fft(np.zeros(awr.adc_shape, np.complex64), awr)
    assert abs((ranges[1] - ranges[0]) - 0.045321) < 2e-6
    assert abs(ranges[-1] + (ranges[1] - ranges[0]) - 5.8010) < 1e-3
    # zero padding keeps max range, refines the bins
    _, r512 = range_fft(np.zeros(casc.adc_shape, np.complex64), casc, n_fft=512)
    assert abs((r512[1] - r512[0]) - 0.059305 / 2) < 2e-6


def test_02_windows_unit_coherent_gain_and_errors():
    for name in ("hann", "hamming", "blackman", "taylor", "chebyshev", "rect", "none", None):
        for n in (1, 2, 8, 86, 256):
            w = get_window(name, n)
            assert w.shape == (n,)
            assert np.isclose(w.sum(), n)
            assert np.all(np.isfinite(w))
    # Hann is scipy's symmetric one (zero end points), only rescaled
    w = get_window("hann", 16)
    ref = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(16) / 15)
    assert np.allclose(w, ref * 16 / ref.sum())
    with pytest.raises(ConfigError, match="hann"):
        get_window("kaiserish", 8)


@pytest.mark.parametrize("name,rng,az_deg,tol_deg", [
    ("mmwcas", 10.0, -7.3, 0.5),
    ("mmwcas", 10.0, 3.1, 0.5),
    ("mmwcas", 6.5, 8.6, 0.5),
    ("awr1843", 4.0, -6.1, 7.2),
    ("awr1843", 2.5, 9.0, 7.2),
    ("dense16", 6.0, 4.4, 0.5),
    ("dense16", 6.0, -9.5, 0.5),
])
def test_03_point_target_range_azimuth(name, rng, az_deg, tol_deg):
    radar = {"mmwcas": RadarConfig.mmwcas(num_chirps=2), "awr1843": RadarConfig.awr1843(),
             "dense16": RadarConfig.dense(16, 16)}[name]
    adc = _adc(radar, target_at(radar, rng, az_deg * DEG))
    ra, ranges, az = range_azimuth(adc, radar)
    assert ra.shape == (radar.num_samples, 128)
    assert np.all(np.diff(az) > 0)
    i, j = peak_index(ra)
    dr = ranges[1] - ranges[0]
    assert abs(ranges[i] - rng) <= dr, (ranges[i], rng)
    err = abs(az[j] / DEG - az_deg)
    # the peak is one of the two grid azimuths bracketing the true one
    k = int(np.searchsorted(az, az_deg * DEG))
    assert j in (k - 1, k), (az[j] / DEG, az_deg)
    # The 128-point azimuth grid is 2/128 apart in sin(az) * f_d/f_c: half a step is
    # ~0.45 deg near boresight, so a noise-free single target lies within 0.5 deg.
    assert err <= 0.5, err
    # AWR1843: 8 uniform azimuth elements, Rayleigh width 2/8 in spatial frequency
    # (~14.4 deg at boresight); the resolution-limited bound is half of it (7.2 deg),
    # which is what one may promise for a real coarse array.
    assert err <= tol_deg


def test_04_synthesis_matches_direct_formula():
    # The package synthesiser agrees with the straightforward formula used nowhere else.
    radar = RadarConfig.awr1843(num_chirps=4)
    tau = point_target_delays(radar, target_at(radar, 3.0, 10 * DEG))
    a = np.ones_like(tau, dtype=complex)
    s1 = synthesize_adc(radar, a, tau)
    s2 = direct_adc(radar, a, tau)
    assert np.max(np.abs(s1 - s2)) < 1e-3


def test_05_two_targets_two_bins_apart_are_resolved():
    radar = RadarConfig.mmwcas(num_chirps=1)
    dr = C / (2 * 78.986e12 * 256 / 8e6)              # by hand, 5.93 cm
    k0 = 100

    def adc_for(bins):
        # far-field boresight targets exactly on range-bin centres: tau = k fs / (S N)
        tau = np.array([k * 8e6 / (78.986e12 * 256) for k in bins])
        return synthesize_adc(radar, np.ones((1, 1, len(bins)), complex),
                              np.broadcast_to(tau, (12, 16, len(bins))))

    # rectangular window: Rayleigh resolution = 1 bin, a null between the two peaks
    ra, ranges, az = range_azimuth(adc_for([k0, k0 + 2]), radar, range_window="rect")
    prof = ra[:, np.argmax(ra.max(axis=0))]
    assert abs(ranges[k0] - k0 * dr) < 1e-9 + 1e-6
    assert prof[k0 + 1] < 0.05 * min(prof[k0], prof[k0 + 2])
    top2 = np.sort(np.argsort(prof)[-2:])
    assert list(top2) == [k0, k0 + 2]
    # Hann (main lobe +-2 bins): 3 bins apart is resolved whatever the phases
    ra, _, _ = range_azimuth(adc_for([k0, k0 + 3]), radar)
    prof = ra[:, np.argmax(ra.max(axis=0))]
    assert prof[k0 + 1] < 0.6 * prof[k0] and prof[k0 + 2] < 0.6 * prof[k0 + 3]


def test_06_dense_range_azimuth_elevation():
    radar = RadarConfig.dense(16, 16)
    az0, el0, rng = 6.0 * DEG, -8.0 * DEG, 6.0
    adc = _adc(radar, target_at(radar, rng, az0, el0))
    rae, ranges, az, el = range_azimuth_elevation(adc, radar)
    assert rae.shape == (256, 128, 128)
    i, j, k = peak_index(rae)
    assert abs(ranges[i] - rng) <= ranges[1] - ranges[0]
    # the azimuth axis measures sin(az) cos(el): expected peak at arcsin(sin az cos el)
    az_expected = math.asin(math.sin(az0) * math.cos(el0))
    assert abs(az[j] - az_expected) / DEG <= 0.5
    assert abs(el[k] - el0) / DEG <= 0.5


def test_07_dense_100x100_rae():
    radar = RadarConfig.dense(100, 100)
    az0, el0, rng = -4.0 * DEG, 5.0 * DEG, 7.0
    adc = _adc(radar, target_at(radar, rng, az0, el0))
    rae, ranges, az, el = range_azimuth_elevation(adc, radar)
    i, j, k = peak_index(rae)
    assert abs(ranges[i] - rng) <= ranges[1] - ranges[0]
    assert abs(az[j] - math.asin(math.sin(az0) * math.cos(el0))) / DEG <= 0.5
    assert abs(el[k] - el0) / DEG <= 0.5
    # 100 x 100 elements: 3 dB beam ~ 1.2 deg, far below a 10 deg offset
    assert rae[i, j, k] > 30 * rae[i, j, (k + 10) % 128]


def test_08_virtual_array_facts_from_the_layouts():
    casc = VirtualArray(RadarConfig.mmwcas())
    # TI layout (README / ColoRadar antenna_cfg): 86 positions at elevation 0 plus the
    # 3 elevated Tx (el 1, 4, 6) x 16 distinct Rx positions = 134 unique elements.
    # (The paper's text says 136; the layout tables give 134.)
    assert casc.num_unique == 86 + 3 * 16
    assert casc.azimuth_row == 0
    assert int((casc.counts[0] > 0).sum()) == 86       # "86 uniformly sampled along azimuth"
    assert casc.row_support == (0, 86)
    # row phase centre: mean Tx az 16, mean Rx az (6 + 50 + 396) / 16 = 28.25 (lambda/2 at
    # 76.8 GHz = 1.95171 mm) -> (16 + 28.25) / 2 * 1.95171 mm = 4.318 cm to the left
    assert np.allclose(casc.phase_centre(), [0, 22.125 * C / (2 * 76.8e9), 0])
    awr = VirtualArray(RadarConfig.awr1843())
    assert awr.num_unique == 12 and int((awr.counts[awr.azimuth_row] > 0).sum()) == 8
    dense = VirtualArray(RadarConfig.dense(100, 100))   # half-integer positions
    assert dense.num_unique == 10000 and (dense.n_el, dense.n_az) == (100, 100)
    # duplicates are averaged: scatter the tx index, a shared cell holds the mean
    radar = RadarConfig.mmwcas()
    ch = np.broadcast_to(np.arange(12.0)[:, None], (12, 16)).astype(np.complex64)
    grid = casc.to_grid(ch)
    # azimuth 12 = Tx az 0 (tx 11) + Rx az 12 (rx 1) = Tx az 12 (tx 8) + Rx az 0 (rx 12)
    e, a = 0, 12
    same = (casc.el_index == e) & (casc.az_index == a)
    assert same[11, 1] and same[8, 12] and casc.counts[e, a] == same.sum() >= 2
    assert np.isclose(grid[e, a].real, np.arange(12.0)[np.nonzero(same)[0]].mean())
    assert np.all(grid[~casc.filled] == 0)
    # off-grid layouts are refused
    bad = radar.replace(rx_positions=radar.rx_positions + np.array([0, 0.3e-3, 0]) *
                        (np.arange(16) % 2)[:, None])
    with pytest.raises(ConfigError, match="lambda/2 grid"):
        VirtualArray(bad)


def test_09_doppler_awr1843_tdm():
    radar = RadarConfig.awr1843(num_chirps=64)
    # by hand: f_c = 77e9 + 64.598e12 (8.66e-6 + 64 / 2.5e6) = 79.2131 GHz,
    # lambda = 3.7847 mm, T_loop = 3 (7 + 61.89) us = 206.67 us,
    # v_res = lambda / (2 * 64 * T_loop) = 0.14307 m/s, v_max = lambda / (4 T_loop) = 4.578 m/s
    lam = C / (77e9 + 64.598e12 * (8.66e-6 + 64 / 2.5e6))
    t_loop = 3 * (7e-6 + 61.89e-6)
    v_res = lam / (2 * 64 * t_loop)
    assert abs(v_res - 0.14307) < 1e-4
    for v, az_deg in ((2.0, -6.1), (-1.5, 4.0)):
        adc = _adc(radar, target_at(radar, 3.0, az_deg * DEG), velocity=v)
        rd, ranges, vel = range_doppler(adc, radar)
        assert rd.shape == (128, 64) and vel.shape == (64,)
        assert abs(vel[1] - vel[0] - v_res) < 1e-9 + 1e-6
        i, j = peak_index(rd)
        assert abs(vel[j] - v) <= v_res, (vel[j], v)   # sign: positive = receding
        assert abs(ranges[i] - 3.0) <= 2 * (ranges[1] - ranges[0])   # moves 2.6 cm in the frame
        ra, _, az = range_azimuth(adc, radar, doppler="noncoherent")
        err = abs(az[peak_index(ra)[1]] / DEG - az_deg)
        assert err <= 0.5
        # without the Tx-slot compensation the phase step between Tx0 and Tx2
        # (2 pi f_D 2 T_chirp ~ 50 deg) moves the beam by several degrees
        ra_nc, _, _ = range_azimuth(adc, radar, doppler="noncoherent", tdm_compensation=False)
        err_nc = abs(az[peak_index(ra_nc)[1]] / DEG - az_deg)
        assert err_nc > err + 2.0


def test_10_doppler_cascade_tdm_phases():
    radar = RadarConfig.mmwcas(num_chirps=16)
    lam = radar.wavelength
    t_loop = 12 * 45e-6
    v_res = lam / (2 * 16 * t_loop)
    v = 4 * v_res                                       # exactly on a Doppler bin
    az_deg = 5.0
    pos = target_at(radar, 8.0, az_deg * DEG)
    adc = _adc(radar, pos, velocity=v)
    rd, ranges, vel = range_doppler(adc, radar)
    i, j = peak_index(rd)
    assert abs(vel[j] - v) <= v_res
    assert j == 16 // 2 + 4
    # per-channel phases at the peak bin vs a static target: compensation removes the
    # Tx-slot ramp 2 pi f_D s T_chirp (s = 0..11, 45 us per slot)
    rf, _ = range_fft(adc, radar)
    dop, _ = doppler_fft(rf, radar)
    va = VirtualArray(radar)
    f_d = np.array([2 * v / lam])
    comp = va.tdm_compensate(dop[:, :, j:j + 1, i], f_d)[:, :, 0]
    static, _ = range_fft(_adc(radar, pos).mean(axis=2), radar)
    ref = static[:, :, i]
    assert _phase_spread_deg(comp / ref) < 2.0
    assert _phase_spread_deg(dop[:, :, j, i] / ref) > 20.0
    ra, _, az = range_azimuth(adc, radar, doppler="noncoherent")
    assert abs(az[peak_index(ra)[1]] / DEG - az_deg) <= 0.5


def test_11_bad_input_is_refused_with_clear_errors():
    radar = RadarConfig.awr1843(num_chirps=2)
    good = np.zeros(radar.adc_shape, np.complex64)
    with pytest.raises(InputValueError, match="shape"):
        range_azimuth(good[:, :, :, :-1], radar)
    with pytest.raises(InputValueError, match="shape"):
        range_azimuth(good[None], radar)
    bad = good.copy()
    bad[0, 0, 0, 3] = np.nan
    with pytest.raises(InputValueError, match="NaN"):
        range_azimuth(bad, radar)
    with pytest.raises(InputValueError, match="NaN"):
        range_azimuth_elevation(bad, radar)
    with pytest.raises(InputValueError, match="NaN"):
        range_doppler(bad, radar)
    with pytest.raises(ConfigError, match="doppler"):
        range_azimuth(good, radar, doppler="coherent-ish")
    with pytest.raises(ConfigError, match="choose one of"):
        range_azimuth(good, radar, azimuth_window="gauss")
