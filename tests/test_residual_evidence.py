"""Evidence checks used on the measured captures, against hand-built references."""
from __future__ import annotations

import numpy as np
import pytest

from sionna_mmir.fmcw.synthesize import synthesize_adc
from sionna_mmir.radar.config import RadarConfig
from sionna_mmir.residual.evidence import (near_range_evidence, near_range_similarity,
                                           peak_evidence, track_evidence)

C = 299_792_458.0


def _tone_channels(radar, r_m, phases, amps):
    """``[T, R, N]``: one target at ``r_m`` with per-channel complex gains."""
    adc = synthesize_adc(radar, np.ones((radar.num_tx, radar.num_rx, 1)),
                         np.full((radar.num_tx, radar.num_rx, 1), 2 * r_m / C))[:, :, 0]
    return adc * (amps * np.exp(1j * phases))[..., None]


def _ti_extras(adc):
    """What TI's script stores: the 5x zero-padded, windowed FFT peak per channel."""
    n = adc.shape[-1]
    k = np.arange(1, n + 1)
    w = 0.5 - 0.5 * np.cos(2 * np.pi * k / (n + 1))
    spec = np.fft.fft(adc * w / np.sqrt(np.mean(w ** 2)), 5 * n, axis=-1)
    peak = np.argmax(np.abs(spec), axis=-1)
    return {"PeakValMat": np.take_along_axis(spec, peak[..., None], -1)[..., 0],
            "RangeMat": peak + 1}                                          # 1-based, as TI


def test_01_peak_evidence_is_zero_for_the_capture_itself_and_sees_phase_errors():
    radar = RadarConfig.awr1843(num_chirps=1, num_samples=128)
    T, R = radar.num_tx, radar.num_rx
    rng = np.random.default_rng(0)
    ph, amp = rng.uniform(-np.pi, np.pi, (T, R)), rng.uniform(0.5, 1.5, (T, R))
    meas = _tone_channels(radar, 3.1, ph, amp)
    ex = _ti_extras(meas)
    same = peak_evidence(meas * 2.0 * np.exp(0.7j), ex)        # common gain removed
    assert same["phase_rms_deg"] < 1e-6 and same["amplitude_rms_db"] < 1e-6
    err = np.radians(10) * rng.choice([-1.0, 1.0], (T, R))
    off = peak_evidence(_tone_channels(radar, 3.1, ph + err, amp), ex)
    # +-10 deg with random signs: RMS about the circular mean is 10 deg * sqrt(1 - mean^2)
    m = np.mean(err)
    assert off["phase_rms_deg"] == pytest.approx(np.degrees(np.sqrt(np.mean((err - m) ** 2))),
                                                 rel=0.02)


def test_02_near_range_evidence_separable_vs_arbitrary_pattern():
    radar = RadarConfig.awr1843(num_chirps=2, num_samples=128)
    T, R = radar.num_tx, radar.num_rx
    rng = np.random.default_rng(1)
    u = np.exp(1j * rng.uniform(-3, 3, T)) * rng.uniform(0.5, 1.5, T)
    v = np.exp(1j * rng.uniform(-3, 3, R)) * rng.uniform(0.5, 1.5, R)
    sep = _tone_channels(radar, 0.15, np.angle(np.outer(u, v)), np.abs(np.outer(u, v)))
    res = np.broadcast_to(sep[None, :, :, None], (1, T, R, 2, 128))
    e = near_range_evidence(res, radar)
    assert e["rank1_share"] > 0.999
    assert e["near_share"] > 0.95
    assert abs(e["strongest_near_bin_m"] - 0.15) <= radar.range_resolution
    arb = rng.normal(size=(T, R)) + 1j * rng.normal(size=(T, R))
    res2 = np.broadcast_to(_tone_channels(radar, 0.15, np.angle(arb), np.abs(arb))[None, :, :, None],
                           (1, T, R, 2, 128))
    s = np.linalg.svd(arb, compute_uv=False) ** 2
    assert near_range_evidence(res2, radar)["rank1_share"] == pytest.approx(s[0] / s.sum(),
                                                                            abs=0.02)


def test_03_track_evidence_follows_a_linear_mover():
    radar = RadarConfig.awr1843(num_chirps=1, num_samples=128)
    T, R = radar.num_tx, radar.num_rx
    ranges = 1.0 + 0.02 * np.arange(30)
    frames = np.stack([_tone_channels(radar, r, np.zeros((T, R)), np.ones((T, R)))[:, :, None]
                       for r in ranges])
    ev = track_evidence(ranges, frames, radar)
    # model-free peak on a 4x padded grid: within half a padded bin
    assert ev["median_abs_diff_m"] < radar.range_resolution / 4
    ev_bad = track_evidence(ranges + 0.5, frames, radar)
    assert ev_bad["median_abs_diff_m"] > 0.4


def test_04_near_range_similarity_of_two_captures():
    radar = RadarConfig.awr1843(num_chirps=1, num_samples=128)
    T, R = radar.num_tx, radar.num_rx
    rng = np.random.default_rng(3)
    pat = rng.normal(size=(T, R)) + 1j * rng.normal(size=(T, R))
    a = _tone_channels(radar, 0.15, np.angle(pat), np.abs(pat))[None, :, :, None]
    same = near_range_similarity(a, 3j * a, radar)
    assert same["coherence"] == pytest.approx(1.0, abs=1e-9)
    assert same["db_correlation"] == pytest.approx(1.0, abs=1e-9)
    other = rng.normal(size=(T, R)) + 1j * rng.normal(size=(T, R))
    b = _tone_channels(radar, 0.15, np.angle(other), np.abs(other))[None, :, :, None]
    ref = abs(np.vdot(pat, other)) / (np.linalg.norm(pat) * np.linalg.norm(other))
    assert near_range_similarity(a, b, radar)["coherence"] == pytest.approx(ref, abs=0.02)
