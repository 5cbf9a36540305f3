"""Tests for :mod:`sionna_mmir.bsdf`: chi-square sampling tests (as in Mitsuba's
``chi2`` tests), pdf normalisation, reciprocity, albedo bound and AD gradients.

Histograms are taken in the frame of the mirror direction ``mu = reflect(wi)``
over ``(x, phi')`` with the warped polar coordinate
``x = log(1 + s (1 - cos theta')) / log(1 + 2 s)`` (``s`` ~ lobe concentration),
so peaked lobes are resolved; expected counts integrate the pdf over each bin
with a midpoint rule (Jacobian ``|d cos theta'/dx|`` included).
"""
from __future__ import annotations

import numpy as np
import pytest

from sionna_mmir.bsdf import ggx, lambertian, mmwave, vmf
from sionna_mmir.bsdf._common import dr, mi

from helpers import sphere_chi2

N_SAMPLES = 200_000
N_X, N_PHI, SUB = 20, 40, 12
LAMBDA = 3.9e-3


# ---------------------------------------------------------------- helpers
def vec(a):
    a = np.asarray(a, dtype=np.float32)
    return mi.Vector3f(mi.Float(a[..., 0]), mi.Float(a[..., 1]), mi.Float(a[..., 2]))


def to_np(v):
    return np.stack([np.array(v.x), np.array(v.y), np.array(v.z)], axis=-1).astype(np.float64)


def wi_deg(theta_deg, n=1):
    t = np.radians(theta_deg)
    return np.tile([np.sin(t), 0.0, np.cos(t)], (n, 1))


def frame(mu):
    mu = mu / np.linalg.norm(mu)
    a = np.array([1.0, 0, 0]) if abs(mu[0]) < 0.9 else np.array([0, 1.0, 0])
    s = np.cross(mu, a)
    s /= np.linalg.norm(s)
    return s, np.cross(mu, s), mu


def chi2_case(sample_fn, pdf_fn, theta_deg, scale, seed=1, n_uniform=2):
    """Return (p_value, integral of pdf over the sphere)."""
    rng = np.random.default_rng(seed)
    wi_np = wi_deg(theta_deg)[0]
    u = rng.random((N_SAMPLES, 3)).astype(np.float32)
    wi = vec(np.tile(wi_np, (N_SAMPLES, 1)))
    wo, _ = sample_fn(wi, mi.Float(u[:, 2]), mi.Point2f(mi.Float(u[:, 0]), mi.Float(u[:, 1])))
    w = to_np(wo)
    s, t, m = frame(np.array([-wi_np[0], -wi_np[1], wi_np[2]]))
    return sphere_chi2(w, m, s, t, scale,
                       lambda dirs: np.array(pdf_fn(vec(np.tile(wi_np, (len(dirs), 1))), vec(dirs))),
                       N_X, N_PHI, SUB)


def mm_params(sigma_over_lambda, lc_over_lambda, tau, gate=1.0):
    return mmwave.MMWaveParams(sigma_h=sigma_over_lambda * LAMBDA, l_c=lc_over_lambda * LAMBDA,
                               tau=tau, wavelength=LAMBDA, gate=gate)


ANGLES = [0.0, 45.0, 70.0]
MM_CASES = [  # (sigma/lambda, l_c/lambda, tau, incidence angle)
    (0.02, 10.0, 0.5, 30.0),
    (0.08, 3.0, 0.7, 60.0),
    (0.3, 5.0, 0.3, 10.0),
]


# ---------------------------------------------------------------- 1. chi2: Lambertian
@pytest.mark.parametrize("theta", [0.0, 60.0])
def test_01_chi2_lambertian(theta):
    p, integral = chi2_case(lambda wi, u1, u2: lambertian.sample(wi, u2),
                            lambda wi, wo: lambertian.pdf(wi, wo), theta, 1.0)
    assert p > 0.01 and abs(integral - 1) < 1e-2, (p, integral)


# ---------------------------------------------------------------- 2. chi2: vMF
@pytest.mark.parametrize("kappa", [2.0, 50.0, 500.0])
@pytest.mark.parametrize("theta", ANGLES)
def test_02_chi2_vmf(kappa, theta):
    p, integral = chi2_case(lambda wi, u1, u2: vmf.sample(wi, u2, kappa),
                            lambda wi, wo: vmf.pdf(wi, wo, kappa), theta, kappa)
    assert p > 0.01 and abs(integral - 1) < 1e-2, (p, integral)


# ---------------------------------------------------------------- 3. chi2: GGX
@pytest.mark.parametrize("alpha", [0.1, 0.5])
@pytest.mark.parametrize("theta", ANGLES)
def test_03_chi2_ggx(alpha, theta):
    scale = 1.0 / (2 * alpha ** 2)
    p, integral = chi2_case(lambda wi, u1, u2: ggx.sample(wi, u2, alpha),
                            lambda wi, wo: ggx.pdf(wi, wo, alpha), theta, scale)
    assert p > 0.01 and abs(integral - 1) < 1e-2, (p, integral)


# ---------------------------------------------------------------- 4. chi2: combined mmWave BSDF
@pytest.mark.parametrize("case", MM_CASES)
def test_04_chi2_mmwave(case):
    sol, lcl, tau, theta = case
    prm = mm_params(sol, lcl, tau)
    scale = float(max(np.array(prm.kappa())[0], 1 / (2 * np.array(prm.alpha())[0] ** 2)))
    p, integral = chi2_case(lambda wi, u1, u2: mmwave.sample(wi, u1, u2, prm),
                            lambda wi, wo: mmwave.pdf(wi, wo, prm), theta, scale)
    assert p > 0.01 and abs(integral - 1) < 1e-2, (p, integral)


# ---------------------------------------------------------------- 5. sample's pdf == pdf()
def test_05_sample_pdf_consistent():
    rng = np.random.default_rng(5)
    n = 4096
    u = rng.random((n, 3)).astype(np.float32)
    u2 = mi.Point2f(mi.Float(u[:, 0]), mi.Float(u[:, 1]))
    wi = vec(wi_deg(40.0, n))
    prm = mm_params(0.08, 3.0, 0.6)
    for wo, p, ref in [
        (*vmf.sample(wi, u2, 20.0), lambda w: vmf.pdf(wi, w, 20.0)),
        (*ggx.sample(wi, u2, 0.3), lambda w: ggx.pdf(wi, w, 0.3)),
        (*lambertian.sample(wi, u2), lambda w: lambertian.pdf(wi, w)),
        (*mmwave.sample(wi, mi.Float(u[:, 2]), u2, prm), lambda w: mmwave.pdf(wi, w, prm)),
    ]:
        np.testing.assert_allclose(np.array(p), np.array(ref(wo)), rtol=1e-4, atol=1e-6)
        assert np.all(np.array(p) > 0)


# ---------------------------------------------------------------- 6. reciprocity
def test_06_reciprocity():
    rng = np.random.default_rng(6)
    n = 2000

    def hemi():
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    a, b = vec(hemi()), vec(hemi())
    for f in (lambda x, y: lambertian.eval(x, y), lambda x, y: vmf.eval(x, y, 30.0),
              lambda x, y: ggx.eval(x, y, 0.3)):
        np.testing.assert_allclose(np.array(f(a, b)), np.array(f(b, a)), rtol=1e-4, atol=1e-7)


# ---------------------------------------------------------------- 7. albedo <= 1
@pytest.mark.parametrize("sol", [0.0, 0.02, 0.1, 0.5])
def test_07_albedo_bounded(sol):
    """Importance-sampled albedo ``E[f cos_o / pdf]``; pointwise ``f cos_o <= pdf`` too."""
    rng = np.random.default_rng(7)
    n = 50_000
    for lcl in (0.5, 5.0, 50.0):
        for tau in (0.0, 0.5, 1.0):
            prm = mm_params(sol, lcl, tau)
            for theta in (0.0, 45.0, 80.0):
                u = rng.random((n, 3)).astype(np.float32)
                wi = vec(wi_deg(theta, n))
                wo, p = mmwave.sample(wi, mi.Float(u[:, 2]),
                                      mi.Point2f(mi.Float(u[:, 0]), mi.Float(u[:, 1])), prm)
                f = np.array(mmwave.eval(wi, wo, prm)) * np.maximum(np.array(wo.z), 0)
                p = np.array(p)
                wgt = np.where(p > 0, f / np.where(p > 0, p, 1), 0)
                assert wgt.max() <= 1 + 1e-3, (sol, lcl, tau, theta, wgt.max())
                assert wgt.mean() <= 1 + 1e-3


# ---------------------------------------------------------------- 8. AD gradients vs finite differences
def _grad_check(fn, x0, rel_step=1e-2):
    """Max relative error of the Dr.Jit gradient vs central differences (float32:
    a 1 % step keeps rounding noise below the O(h^2) truncation error)."""
    x = dr.full(mi.Float, x0, N_GRAD)
    dr.enable_grad(x)
    y = fn(x)
    dr.backward(dr.sum(y))
    g = np.array(dr.grad(x))
    h = rel_step * x0
    fd = (np.array(fn(mi.Float(x0 + h))) - np.array(fn(mi.Float(x0 - h)))) / (2 * h)
    scale = np.abs(fd).max()
    err = np.abs(g - fd) / np.maximum(np.abs(fd), 1e-3 * scale)
    return err.max()


N_GRAD = 64


def _grad_dirs():
    rng = np.random.default_rng(8)
    wi = wi_deg(35.0, N_GRAD)
    mu = np.array([-wi[0, 0], 0, wi[0, 2]])
    v = mu + 0.35 * rng.normal(size=(N_GRAD, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return vec(wi), vec(v / np.linalg.norm(v, axis=1, keepdims=True))


@pytest.mark.parametrize("alpha", [0.1, 0.4])
def test_08_grad_ggx_alpha(alpha):
    wi, wo = _grad_dirs()
    assert _grad_check(lambda a: ggx.eval(wi, wo, a), alpha) < 0.02


@pytest.mark.parametrize("kappa", [3.0, 40.0])
def test_09_grad_vmf_kappa(kappa):
    wi, wo = _grad_dirs()
    assert _grad_check(lambda k: vmf.eval(wi, wo, k), kappa) < 0.02


def test_10_grad_mmwave_params():
    wi, wo = _grad_dirs()
    s0, l0 = 0.08 * LAMBDA, 3.0 * LAMBDA
    e1 = _grad_check(lambda s: mmwave.eval(wi, wo, mmwave.MMWaveParams(s, l0, 0.5, LAMBDA)), s0)
    e2 = _grad_check(lambda l: mmwave.eval(wi, wo, mmwave.MMWaveParams(s0, l, 0.5, LAMBDA)), l0)
    assert e1 < 0.02 and e2 < 0.02, (e1, e2)


def test_11_grad_mmwave_blend_tau():
    """KA/SPM blend tau: AD vs central differences (< 2 %)."""
    wi, wo = _grad_dirs()
    s0, l0 = 0.08 * LAMBDA, 3.0 * LAMBDA
    e = _grad_check(lambda t: mmwave.eval(wi, wo, mmwave.MMWaveParams(s0, l0, t, LAMBDA)), 0.4)
    assert e < 0.02, e
