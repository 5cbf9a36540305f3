"""Tests for :mod:`sionna_mmir.radio_devices.beam_pattern`.

References are independent of the code under test: sphere quadrature on a
(theta, phi) grid (not the separable az/el form the closed form uses), the
Wallis integral by ``scipy.integrate.quad`` for the finite-difference
reference, root finding for beamwidths, Sionna RT's pattern functions called
directly with angles computed here in NumPy, and textbook values (short dipole
D = 1.5, half-wave dipole D = 1.643 [Balanis, Antenna Theory, Ch. 4], the
3GPP TR 38.901 Table 7.3-1 element: 8 dBi peak, -3 dB at 65/2 deg, 30 dB
front-to-back ratio).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, optimize

from sionna_mmir.errors import ConfigError, InputValueError
from sionna_mmir.radio_devices import (
    HALF_POWER_DB,
    QUARTER_POWER_DB,
    BeamPattern,
    CosinePowerPattern,
    IsotropicPattern,
    SionnaPattern,
    cosine_power_normalisation_np,
    make_pattern,
)
from sionna_mmir.radio_devices.beam_pattern import Q_MIN, dr, mi

RNG = np.random.default_rng(1234)


# ---------------------------------------------------------------- helpers
def vec(a):
    a = np.asarray(a, dtype=np.float32).reshape(-1, 3)
    return mi.Vector3f(mi.Float(a[:, 0]), mi.Float(a[:, 1]), mi.Float(a[:, 2]))


def to_np(v):
    return np.stack([np.array(v.x), np.array(v.y), np.array(v.z)], axis=-1).astype(np.float64)


def azel(az, el):
    """Radar-frame unit vectors [..., 3] from azimuth / elevation [rad]."""
    az, el = np.broadcast_arrays(np.asarray(az, float), np.asarray(el, float))
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)


def sphere_grid(n_theta=1000):
    """Midpoint grid over the sphere in Sionna's (theta from +z, phi from +x)."""
    th = (np.arange(n_theta) + 0.5) * np.pi / n_theta
    ph = -np.pi + (np.arange(2 * n_theta) + 0.5) * np.pi / n_theta
    T, P = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1)
    w = np.sin(T) * (np.pi / n_theta) ** 2
    return d.reshape(-1, 3), w.ravel()


def sphere_integral(pattern, n_theta=1000):
    d, w = sphere_grid(n_theta)
    g = np.asarray(pattern.gain(vec(d)), dtype=np.float64)
    return float(np.sum(g * w))


def wallis_quad(p):
    """int_{-pi/2}^{pi/2} cos^p t dt by adaptive quadrature (no Gamma functions)."""
    return 2.0 * integrate.quad(lambda t: np.cos(t) ** p, 0.0, np.pi / 2, epsabs=0,
                                epsrel=1e-13, limit=200)[0]


def gain_ref(q_az, q_el, az, el):
    """Float64 reference gain with a quadrature normalisation."""
    g0 = 4.0 * np.pi / (wallis_quad(q_az) * wallis_quad(q_el + 1.0))
    return g0 * np.cos(az) ** q_az * np.cos(el) ** q_el


def sionna_direct(name, polarization, theta, phi, port=0):
    """Sionna's pattern called directly: (C_theta, C_phi) as complex NumPy."""
    from sionna.rt.antenna_pattern import antenna_pattern_registry

    pat = antenna_pattern_registry.get(name)(polarization=polarization)
    c_t, c_p = pat[port](mi.Float(np.asarray(theta, np.float32)),
                         mi.Float(np.asarray(phi, np.float32)))
    cnp = lambda c: np.array(dr.real(c), np.float64) + 1j * np.array(dr.imag(c), np.float64)  # noqa: E731
    return cnp(c_t), cnp(c_p)


# ---------------------------------------------------------------- tests
def test_01_closed_form_normalisation_and_defaults():
    # hemisphere: G0(0, 0) = 2; separable closed form at the defaults
    assert cosine_power_normalisation_np(0.0, 0.0) == pytest.approx(2.0, rel=1e-12)
    p = CosinePowerPattern()
    qa, qe = p.q_np()
    assert qa[0] == pytest.approx(2.0, rel=1e-6) and qe[0] == pytest.approx(10.0, rel=1e-6)
    g0 = 4 * np.pi / (wallis_quad(2.0) * wallis_quad(11.0))
    assert p.peak_gain_dbi()[0] == pytest.approx(10 * np.log10(g0), abs=1e-5)
    assert 10.0 < p.peak_gain_dbi()[0] < 10.7
    # quarter-power half-widths near +-60 deg (az) and +-30 deg (el)
    bw = np.degrees(p.beamwidth(QUARTER_POWER_DB)[0]) / 2
    assert bw[0] == pytest.approx(60.0, abs=0.01) and bw[1] == pytest.approx(29.47, abs=0.05)
    # Dr.Jit float64 lgamma closed form vs NumPy, from tiny to very large q
    q_az = np.array([Q_MIN, 0.37, 1.0, 2.5, 17.0, 333.3, 5000.0])
    q_el = np.array([Q_MIN, 4.2, 0.5, 10.0, 60.0, 2.0, 9000.0])
    p = CosinePowerPattern(q_az, q_el, n_elements=len(q_az))
    lg0 = np.asarray(p.log_normalisation(), np.float64)
    ref = np.log(cosine_power_normalisation_np(*p.q_np()))
    np.testing.assert_allclose(lg0, ref, rtol=0, atol=2e-6)
    # boresight gain is G0
    g = np.asarray(p.gain(vec(np.tile([1.0, 0, 0], (len(q_az), 1))),
                          mi.UInt32(np.arange(len(q_az)))), np.float64)
    np.testing.assert_allclose(g, np.exp(ref), rtol=2e-6)


@pytest.mark.parametrize("q_az,q_el", [(0.0, 0.0), (2.0, 10.0), (0.5, 1.7), (1.0, 1.0),
                                       (3.3, 25.5), (7.25, 0.3)])
def test_02_directivity_quadrature(q_az, q_el):
    p = CosinePowerPattern(q_az, q_el)
    assert sphere_integral(p) == pytest.approx(4 * np.pi, rel=5e-3)
    # the float64 NumPy path integrates the same way
    d, w = sphere_grid(400)
    assert float(np.sum(p.gain_np(d) * w)) == pytest.approx(4 * np.pi, rel=5e-3)


def test_03_beamwidth_matches_closed_form():
    for q_az, q_el in [(2.0, 10.0), (0.7, 3.3), (5.5, 40.0)]:
        p = CosinePowerPattern(q_az, q_el)
        qa, qe = p.q_np()
        for level_db, frac in ((HALF_POWER_DB, 0.5), (QUARTER_POWER_DB, 0.25), (3.0, 10 ** -0.3)):
            bw = p.beamwidth(level_db)[0]
            g_peak = p.gain_np([1.0, 0.0, 0.0])
            # azimuth cut (el = 0) and elevation cut (az = 0), NumPy and Dr.Jit
            cut_az = lambda a: p.gain_np(azel(a, 0.0)) / g_peak - frac  # noqa: E731
            cut_el = lambda e: p.gain_np(azel(0.0, e)) / g_peak - frac  # noqa: E731
            a3 = optimize.brentq(cut_az, 1e-9, np.pi / 2 - 1e-9, xtol=1e-13)
            e3 = optimize.brentq(cut_el, 1e-9, np.pi / 2 - 1e-9, xtol=1e-13)
            assert 2 * a3 == pytest.approx(bw[0], abs=1e-9)
            assert 2 * e3 == pytest.approx(bw[1], abs=1e-9)
            assert 2 * a3 == pytest.approx(2 * np.arccos(frac ** (1 / qa[0])), abs=1e-9)
            g_dr = np.asarray(p.gain(vec(azel([a3, 0.0, -a3], [0.0, e3, 0.0]))), np.float64)
            np.testing.assert_allclose(g_dr / g_peak, frac, rtol=1e-5)


def test_04_gradient_wrt_q_matches_finite_differences():
    p = CosinePowerPattern(2.7, 8.3)
    qa, qe = (float(v[0]) for v in p.q_np())
    az = np.radians([0.0, 0.0, 25.0, -50.0, 70.0, 10.0])
    el = np.radians([0.0, 15.0, -5.0, 20.0, 0.0, -40.0])
    h = 1e-5
    fd_qa = (gain_ref(qa + h, qe, az, el) - gain_ref(qa - h, qe, az, el)) / (2 * h)
    fd_qe = (gain_ref(qa, qe + h, az, el) - gain_ref(qa, qe - h, az, el)) / (2 * h)
    np.testing.assert_allclose(p.gain_np(azel(az, el)), gain_ref(qa, qe, az, el), rtol=1e-9)
    for key, q, fd in (("log_q_az", qa, fd_qa), ("log_q_el", qe, fd_qe)):
        src = p.params()[key]
        dr.enable_grad(src)
        g = p.gain(vec(azel(az, el)))
        dr.forward(src)  # d/d(log q); chain rule: d/dq = d/d(log q) / q
        ad = np.asarray(dr.grad(g), np.float64) / q
        dr.disable_grad(src)
        # boresight (first entry) has cos = 1: its gradient is the normalisation's alone
        assert abs(fd[0]) > 0.1
        np.testing.assert_allclose(ad, fd, rtol=1e-3, atol=0)


def test_05_gradient_wrt_direction_and_field():
    p = CosinePowerPattern(2.7, 8.3)
    qa, qe = (float(v[0]) for v in p.q_np())
    az0 = np.radians([5.0, -30.0, 60.0])
    el0 = np.radians([-10.0, 20.0, 3.0])
    for which in ("az", "el"):
        az, el = mi.Float(az0.astype(np.float32)), mi.Float(el0.astype(np.float32))
        src = az if which == "az" else el
        dr.enable_grad(src)
        d = mi.Vector3f(dr.cos(el) * dr.cos(az), dr.cos(el) * dr.sin(az), dr.sin(el))
        g, f = p.gain(d), p.field(d)
        dr.forward(src)
        g_ad, f_ad = np.asarray(dr.grad(g), np.float64), np.asarray(dr.grad(f), np.float64)
        g_np = gain_ref(qa, qe, az0, el0)
        tan = np.tan(az0) if which == "az" else np.tan(el0)
        q = qa if which == "az" else qe
        np.testing.assert_allclose(g_ad, -q * tan * g_np, rtol=1e-3)
        np.testing.assert_allclose(f_ad, -0.5 * q * tan * np.sqrt(g_np), rtol=1e-3)
        hh = 1e-6
        step = (hh, 0.0) if which == "az" else (0.0, hh)
        fd = (p.gain_np(azel(az0 + step[0], el0 + step[1]))
              - p.gain_np(azel(az0 - step[0], el0 - step[1]))) / (2 * hh)
        np.testing.assert_allclose(g_ad, fd, rtol=1e-3)
    np.testing.assert_allclose(np.asarray(p.field(vec(azel(az0, el0))), np.float64),
                               np.sqrt(gain_ref(qa, qe, az0, el0)), rtol=1e-5)
    # directly on the vector: finite, zero behind and at the zenith (no NaN)
    d = vec([[0, 0, 1], [-1, 0, 0], [0, 1, 0], [1e-8, 0, 1], [0.6, 0.0, 0.8]])
    dr.enable_grad(d)
    g = p.gain(d)
    dr.backward(dr.sum(g) + dr.sum(p.field(d)))
    grad = to_np(dr.grad(d))
    assert np.all(np.isfinite(grad))
    np.testing.assert_array_equal(grad[:3], 0.0)
    assert np.array(g)[:3].tolist() == [0.0, 0.0, 0.0]


def test_06_per_element_selection():
    q_az, q_el = [1.0, 2.0, 4.0], [5.0, 10.0, 20.0]
    p = CosinePowerPattern(q_az, q_el, n_elements=3, polarization="H")
    d = azel(np.radians(20.0), np.radians(10.0))
    dirs = vec(np.tile(d, (3, 1)))
    g = np.asarray(p.gain(dirs, mi.UInt32([0, 1, 2])), np.float64)
    single = [float(np.asarray(CosinePowerPattern(a, e).gain(vec(d)))[0])
              for a, e in zip(q_az, q_el)]
    np.testing.assert_allclose(g, single, rtol=2e-6)
    assert len(set(np.round(g, 4))) == 3
    # NumPy indices, one index for all queries, and the NumPy path agree
    np.testing.assert_allclose(np.asarray(p.gain(dirs, np.array([2, 1, 0])), np.float64),
                               g[::-1], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(p.gain(dirs, 1), np.float64), g[1], rtol=1e-6)
    np.testing.assert_allclose(p.gain_np(np.tile(d, (3, 1)), np.arange(3)), g, rtol=1e-5)
    # gradients flow only to the selected elements
    dr.enable_grad(p.log_q_az)
    dr.backward(dr.sum(p.gain(dirs, mi.UInt32([1, 1, 1]))))
    grad = np.asarray(dr.grad(p.log_q_az))
    assert grad[0] == 0.0 and grad[2] == 0.0 and grad[1] != 0.0
    dr.disable_grad(p.log_q_az)
    with pytest.raises(InputValueError, match="element"):
        p.gain(dirs)
    with pytest.raises(InputValueError, match="element"):
        p.gain(dirs, np.array([0, 3, 1]))


NAMES = ("iso", "dipole", "hw_dipole", "tr38901")


def test_07_sionna_pattern_matches_sionna_functions():
    d = np.concatenate([azel(RNG.uniform(-np.pi, np.pi, 40), np.arcsin(RNG.uniform(-1, 1, 40))),
                        [[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0.6, -0.8, 0.0]]])
    theta, phi = np.arccos(d[:, 2]), np.arctan2(d[:, 1], d[:, 0])
    for name in NAMES:
        for pol in ("V", "H"):
            sp = SionnaPattern(name, polarization=pol)
            c_t, c_p = sionna_direct(name, pol, theta, phi)
            ref = np.abs(c_t) ** 2 + np.abs(c_p) ** 2
            np.testing.assert_allclose(np.asarray(sp.gain(vec(d)), np.float64), ref,
                                       rtol=2e-5, atol=1e-7)
            np.testing.assert_allclose(sp.gain_np(d), ref, rtol=2e-5, atol=1e-7)
            np.testing.assert_allclose(np.asarray(sp.field(vec(d)), np.float64),
                                       np.sqrt(ref), rtol=2e-5, atol=1e-6)
    # dual-polarised ports
    sp = SionnaPattern("tr38901", polarization="cross", port=1)
    c_t, c_p = sionna_direct("tr38901", "cross", theta, phi, port=1)
    np.testing.assert_allclose(sp.gain_np(d), np.abs(c_t) ** 2 + np.abs(c_p) ** 2, rtol=2e-5)


def test_08_sionna_pattern_closed_forms():
    bore, left, up = [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]
    dip = SionnaPattern("dipole")
    np.testing.assert_allclose(dip.gain_np([bore, left, azel(np.radians(135), 0)]), 1.5, rtol=1e-6)
    assert 10 * np.log10(dip.gain_np(bore)) == pytest.approx(1.76, abs=0.005)
    assert dip.gain_np(up) == pytest.approx(0.0, abs=1e-10)
    el = np.radians([10.0, 30.0, -60.0])
    np.testing.assert_allclose(dip.gain_np(azel(0.3, el)), 1.5 * np.cos(el) ** 2, rtol=1e-5)
    hw = SionnaPattern("hw_dipole")
    assert hw.gain_np(bore) == pytest.approx(1.643, rel=1e-6)
    e = np.radians(40.0)
    assert hw.gain_np(azel(1.0, e)) == pytest.approx(
        1.643 * (np.cos(np.pi / 2 * np.sin(e)) / np.cos(e)) ** 2, rel=1e-5)
    tr = SionnaPattern("tr38901")
    half = np.radians(65.0 / 2)
    db = lambda x: 10 * np.log10(tr.gain_np(x))  # noqa: E731
    assert db(bore) == pytest.approx(8.0, abs=1e-4)                      # 8 dBi peak
    assert db(azel(half, 0.0)) == pytest.approx(5.0, abs=1e-3)           # -3 dB, azimuth
    assert db(azel(-half, 0.0)) == pytest.approx(5.0, abs=1e-3)
    assert db(azel(0.0, half)) == pytest.approx(5.0, abs=1e-3)           # -3 dB, elevation
    assert db([-1.0, 0, 0]) == pytest.approx(8.0 - 30.0, abs=1e-3)       # 30 dB floor
    assert np.all(SionnaPattern("iso").gain_np(sphere_grid(20)[0]) == pytest.approx(1.0))
    # radiated power: dipoles are normalised; tr38901 matches Sionna's efficiency
    assert sphere_integral(dip, 500) == pytest.approx(4 * np.pi, rel=2e-3)
    assert sphere_integral(hw, 500) == pytest.approx(4 * np.pi, rel=5e-3)
    _, _, eta = tr.sionna_antenna_pattern.compute_gain(num_samples=500, verbose=False)
    assert sphere_integral(tr, 500) / (4 * np.pi) == pytest.approx(float(eta[0]), rel=5e-3)


def test_09_polarization_unit_and_transverse():
    d = np.concatenate([azel(RNG.uniform(-np.pi, np.pi, 200), np.arcsin(RNG.uniform(-1, 1, 200))),
                        np.eye(3), -np.eye(3), [[1e-9, 0, 1], [0, 1, 1e-9]]])
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    pats = [CosinePowerPattern(), CosinePowerPattern(polarization="H"), IsotropicPattern(),
            IsotropicPattern("H")] + [SionnaPattern(n, polarization=pol)
                                      for n in NAMES for pol in ("V", "H")]
    for pat in pats:
        e = pat.polarization_np(d)
        assert np.all(np.isfinite(e)), pat
        np.testing.assert_allclose(np.linalg.norm(e, axis=-1), 1.0, atol=1e-5, err_msg=repr(pat))
        np.testing.assert_allclose(np.sum(e * d, axis=-1), 0.0, atol=1e-5, err_msg=repr(pat))
    bore = [1.0, 0, 0]
    np.testing.assert_allclose(CosinePowerPattern().polarization_np(bore), [0, 0, 1], atol=1e-7)
    np.testing.assert_allclose(CosinePowerPattern(polarization="H").polarization_np(bore),
                               [0, 1, 0], atol=1e-7)
    # V off boresight lies in the plane spanned by d and z, pointing up
    dv = azel(0.4, 0.3)
    e = CosinePowerPattern().polarization_np(dv)
    assert np.dot(np.cross(dv, [0, 0, 1.0]), e) == pytest.approx(0.0, abs=1e-6) and e[2] > 0
    # Sionna: field along theta_hat ("V", points down at the horizon) / phi_hat ("H")
    np.testing.assert_allclose(SionnaPattern("tr38901").polarization_np(bore), [0, 0, -1], atol=1e-6)
    np.testing.assert_allclose(SionnaPattern("tr38901", "H").polarization_np(bore), [0, 1, 0],
                               atol=1e-6)
    np.testing.assert_allclose(SionnaPattern("dipole").polarization_np([0, 1.0, 0]), [0, 0, -1],
                               atol=1e-6)


def test_10_make_pattern_factory():
    assert isinstance(make_pattern("cos"), CosinePowerPattern)
    p = make_pattern("cosine", q_az=3.0, n_elements=4)
    assert p.n_elements == 4 and p.q_np()[0] == pytest.approx(3.0, rel=1e-6)
    assert isinstance(make_pattern("iso"), IsotropicPattern)
    sp = make_pattern("sionna:tr38901")
    assert isinstance(sp, SionnaPattern) and sp.name == "tr38901"
    assert make_pattern("sionna:dipole:H").sionna_polarization == "H"
    assert make_pattern(p) is p
    assert isinstance(p, BeamPattern) and p.params().keys() == {"log_q_az", "log_q_el"}
    assert IsotropicPattern().params() == {} and sp.params() == {}
    for bad in ("gaussian", "sionna:", "sionna:foo", "sionna:dipole:Q", 3, None):
        with pytest.raises(ConfigError):
            make_pattern(bad)
    with pytest.raises(ConfigError, match="unknown beam pattern 'gaussian'.*sionna:tr38901"):
        make_pattern("gaussian")
    with pytest.raises(ConfigError, match="Sionna RT provides"):
        make_pattern("sionna:foo")
    with pytest.raises(ConfigError):
        make_pattern("cos", q_zz=1.0)
    with pytest.raises(ConfigError):
        make_pattern(p, q_az=1.0)


def test_11_bad_inputs():
    for kw in ({"q_az": -1.0}, {"q_el": float("nan")}, {"q_az": float("inf")},
               {"q_az": [1.0, 2.0]}, {"n_elements": 0}, {"n_elements": 2.5},
               {"polarization": "X"}, {"q_el": "abc"}):
        with pytest.raises(ConfigError):
            CosinePowerPattern(**kw)
    with pytest.raises(ConfigError, match=">= 0"):
        CosinePowerPattern(q_az=[1.0, -0.5], n_elements=2)
    p = CosinePowerPattern(0.0, 1.0)  # q = 0 is allowed and stored as Q_MIN
    assert p.q_np()[0][0] == pytest.approx(Q_MIN, rel=1e-5)
    with pytest.raises(ConfigError):
        p.set_params({"log_q_az": mi.Float(float("nan"))})
    with pytest.raises(ConfigError):
        p.set_params({"log_q_el": mi.Float([0.0, 1.0])})
    with pytest.raises(ConfigError):
        p.beamwidth(-3.0)
    for d in ([1.0, 0.0], [[1.0, float("nan"), 0.0]], np.zeros((0, 3))):
        with pytest.raises(InputValueError):
            p.gain(d)
        with pytest.raises(InputValueError):
            p.gain_np(d)
    for kw in ({"name": "nope"}, {"name": "dipole", "polarization": "Z"},
               {"name": "dipole", "polarization_model": "x"}, {"name": "dipole", "port": 1}):
        with pytest.raises(ConfigError):
            SionnaPattern(**kw)


def test_12_learn_q_from_samples():
    """Adam on log q recovers the exponents of a target pattern (the fit's use)."""
    target = CosinePowerPattern(3.0, 6.0)
    d = azel(RNG.uniform(-1.3, 1.3, 300), RNG.uniform(-1.0, 1.0, 300))
    dirs = vec(d)
    y = dr.detach(dr.log(target.gain(dirs)))
    p = CosinePowerPattern()  # (2, 10)
    opt = mi.ad.Adam(lr=0.05, params=p.params())
    for _ in range(150):
        p.set_params(opt)
        loss = dr.mean(dr.square(dr.log(p.gain(dirs)) - y))
        dr.backward(loss)
        opt.step()
    p.set_params(opt)
    qa, qe = p.q_np()
    assert qa[0] == pytest.approx(3.0, rel=1e-2) and qe[0] == pytest.approx(6.0, rel=1e-2)
    assert math.isfinite(float(loss[0]))
