"""Table 2 metrics: definitions checked on hand-computed cases and known properties."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sionna_mmir import metrics
from sionna_mmir.errors import InputValueError
from sionna_mmir.metrics import (adc_log_magnitude_mse, adc_minmax_magnitude_mse, all_metrics,
                                 minmax_normalize, pearson, psnr, ra_loss, rmse, ssim)


def _ssim_bruteforce(x, y, sigma=1.5, k1=0.01, k2=0.03, L=1.0):
    """Independent SSIM: explicit 11 x 11 Gaussian windows, 'valid' positions only."""
    r = 5
    g = np.exp(-(np.arange(-r, r + 1) ** 2) / (2 * sigma ** 2))
    w = np.outer(g, g)
    w /= w.sum()
    c1, c2 = (k1 * L) ** 2, (k2 * L) ** 2
    vals = []
    for i in range(r, x.shape[0] - r):
        for j in range(r, x.shape[1] - r):
            px = x[i - r:i + r + 1, j - r:j + r + 1]
            py = y[i - r:i + r + 1, j - r:j + r + 1]
            mx, my = np.sum(w * px), np.sum(w * py)
            vx = np.sum(w * (px - mx) ** 2)
            vy = np.sum(w * (py - my) ** 2)
            cxy = np.sum(w * (px - mx) * (py - my))
            vals.append(((2 * mx * my + c1) * (2 * cxy + c2))
                        / ((mx ** 2 + my ** 2 + c1) * (vx + vy + c2)))
    return float(np.mean(vals))


def test_01_minmax_normalize():
    x = np.array([[2.0, 4.0], [6.0, 10.0]])
    assert np.allclose(minmax_normalize(x), [[0, 0.25], [0.5, 1.0]])
    assert np.array_equal(minmax_normalize(np.full((3, 3), 7.0)), np.zeros((3, 3)))
    with pytest.raises(InputValueError, match="NaN"):
        minmax_normalize(np.array([1.0, np.nan]))


def test_02_mse_family_hand_values():
    a = np.array([0.0, 1.0, 0.0, 1.0])
    b = np.array([0.0, 1.0, 0.1, 1.0])
    # both already span [0, 1]; one bin differs by 0.1 -> MSE = 0.01 / 4
    assert math.isclose(ra_loss(a, b), 0.0025)
    assert math.isclose(rmse(a, b), 0.05)
    assert math.isclose(psnr(a, b), 10 * math.log10(1 / 0.0025))      # 26.0206 dB
    assert math.isclose(psnr(a, b), 26.0206, abs_tol=1e-4)
    # min-max normalisation: scale and offset of either map do not matter
    assert math.isclose(ra_loss(5 * a + 3, 0.2 * b - 1), 0.0025)
    assert math.isclose(ra_loss(a, b), rmse(a, b) ** 2)
    assert psnr(a, a) == math.inf
    assert rmse(a, a) == 0.0
    # without normalisation: constant offset 0.1 -> MSE 0.01 -> 20 dB
    assert math.isclose(psnr(np.zeros(9), np.full(9, 0.1), normalize=False), 20.0)


def test_03_pearson_hand_values():
    assert math.isclose(pearson([1.0, 2.0, 3.0], [1.0, 3.0, 2.0]), 0.5)   # cov 1, var 2, 2
    x = np.random.default_rng(1).random((8, 9))
    assert math.isclose(pearson(x, 3 * x + 2), 1.0)
    assert math.isclose(pearson(x, -x), -1.0)
    # constant maps: undefined correlation -> 1 if equal, else 0 (documented)
    assert pearson(np.ones(4), np.ones(4)) == 1.0
    assert pearson(np.ones(4), np.arange(4.0)) == 0.0


def test_04_ssim_matches_bruteforce_and_properties():
    rng = np.random.default_rng(0)
    x = rng.random((20, 24))
    y = np.clip(x + 0.2 * rng.standard_normal(x.shape), 0, 1)
    ref = _ssim_bruteforce(x, y)
    assert math.isclose(ssim(x, y, normalize=False), ref, rel_tol=1e-9, abs_tol=1e-12)
    assert math.isclose(ssim(x, x), 1.0)
    assert math.isclose(ssim(x, y), ssim(y, x), rel_tol=1e-12)
    # more noise -> lower SSIM
    vals = [ssim(x, np.clip(x + s * rng.standard_normal(x.shape), 0, 1))
            for s in (0.02, 0.1, 0.3, 0.6)]
    assert all(v1 > v2 for v1, v2 in zip(vals, vals[1:])) and vals[0] < 1.0


def test_05_ssim_hand_computed_constant_shift():
    # constants 0.2 vs 0.5: no structure, SSIM = (2 ab + C1) / (a^2 + b^2 + C1)
    c1 = (0.01 * 1.0) ** 2
    expected = (2 * 0.2 * 0.5 + c1) / (0.2 ** 2 + 0.5 ** 2 + c1)       # 0.68976
    got = ssim(np.full((16, 16), 0.2), np.full((16, 16), 0.5), normalize=False)
    assert math.isclose(got, expected, rel_tol=1e-9)
    assert math.isclose(got, 0.68976, abs_tol=1e-5)
    # linear ramp a and b = a + d: inside the image the Gaussian mean of a ramp is the
    # ramp itself and variances / covariance are equal, so the structure term is 1:
    # SSIM(i, j) = (2 m (m + d) + C1) / (m^2 + (m + d)^2 + C1) with m = a(i, j)
    cols = np.arange(30)
    a = np.tile(0.1 + 0.02 * cols, (18, 1))
    d = 0.15
    m = a[5:-5, 5:-5]
    expected = np.mean((2 * m * (m + d) + c1) / (m ** 2 + (m + d) ** 2 + c1))
    assert math.isclose(ssim(a, a + d, normalize=False), expected, rel_tol=1e-9)


def test_06_adc_metrics_hand_values():
    a = np.array([1.0 + 0j, 0.1j])
    b = np.array([2.0, 0.02])           # same peak-normalised pattern as [1, 0.01]
    # dB: a -> [0, -20], b -> [0, -40]; mean square difference (0 + 400) / 2 = 200 dB^2
    assert math.isclose(adc_log_magnitude_mse(a, b), 200.0, rel_tol=1e-4)
    # peak normalisation: scaling does not matter; identical -> 0
    z = np.random.default_rng(3).standard_normal((3, 4, 2, 8)) * (1 + 1j)
    assert adc_log_magnitude_mse(z, 10 * z) < 1e-20
    # the -120 dB floor: a zero sample against a full-scale one costs 120^2 / n
    assert math.isclose(adc_log_magnitude_mse(np.array([1.0, 0.0]), np.array([1.0, 1.0])),
                        120.0 ** 2 / 2, rel_tol=1e-4)
    # min-max magnitudes: [0, .5, 1] vs [0, 1, 1] -> 0.25 / 3
    assert math.isclose(adc_minmax_magnitude_mse(np.array([0, 1j, 2]), np.array([0, 2, -2])),
                        0.25 / 3)


def test_07_bad_input():
    with pytest.raises(InputValueError, match="shape"):
        ra_loss(np.zeros((3, 4)), np.zeros((4, 3)))
    with pytest.raises(InputValueError, match="NaN"):
        ssim(np.zeros((3, 4)), np.full((3, 4), np.nan))
    with pytest.raises(InputValueError, match="complex"):
        pearson(np.zeros(3, complex), np.zeros(3))
    with pytest.raises(InputValueError, match="shape"):
        adc_log_magnitude_mse(np.zeros((2, 3), complex), np.zeros((3, 2), complex))
    with pytest.raises(InputValueError, match="NaN"):
        adc_minmax_magnitude_mse(np.array([1, np.nan * 1j]), np.array([1, 1j]))


def test_08_all_metrics():
    rng = np.random.default_rng(5)
    ra = rng.random((32, 40))
    adc = rng.standard_normal((2, 3, 4, 16)) + 1j * rng.standard_normal((2, 3, 4, 16))
    out = all_metrics(ra, 2 * ra + 1, adc, adc)
    assert set(out) == {"ra_correlation", "ra_psnr", "ra_ssim", "ra_rmse",
                        "adc_log_mag_mse", "adc_minmax_mag_mse"}
    # affine copies normalise to the same map (up to rounding)
    assert math.isclose(out["ra_correlation"], 1.0) and out["ra_psnr"] > 200
    assert math.isclose(out["ra_ssim"], 1.0) and out["ra_rmse"] < 1e-10
    assert all_metrics(ra, ra)["ra_psnr"] == math.inf
    assert out["adc_log_mag_mse"] == 0.0 and out["adc_minmax_mag_mse"] == 0.0
    noisy = all_metrics(ra, ra + 0.3 * rng.random(ra.shape))
    assert math.isnan(noisy["adc_log_mag_mse"]) and math.isnan(noisy["adc_minmax_mag_mse"])
    assert 0 < noisy["ra_correlation"] < 1 and noisy["ra_ssim"] < 1
    assert math.isclose(noisy["ra_psnr"], -20 * math.log10(noisy["ra_rmse"]))
    assert callable(metrics.ra_loss)
