"""Factorised ADC synthesis (no ``[tx, rx, path]`` expansion): equality with the
expanded synthesiser, exact adjoints, the Dr.Jit node, bad input, and the
solver's factorised paths.

Paths factor as ``a[t, r, p] = c[p] g_t[t, p] g_r[r, p]``,
``tau[t, r, p] = tau_t[t, p] + tau_r[r, p]``, ``tau_rate[t, r, p] = rho[p]``.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from helpers import square_plate

import sionna_mmir  # noqa: F401
from sionna_mmir import RadarConfig, SPEED_OF_LIGHT
from sionna_mmir.errors import InputValueError
from sionna_mmir.fmcw import synthesize_adc, synthesize_adc_basic
from sionna_mmir.fmcw.synthesize_factorised import (
    FactorisedSynthesis, check_factor_inputs, synthesize_adc_factorised,
    synthesize_adc_factorised_vjp)

C = SPEED_OF_LIGHT
NAMES = ("c", "g_t", "tau_t", "g_r", "tau_r", "tau_rate")


def _cascade_cut(num_chirps=3):
    """MMWCAS waveform on 5 Tx x 7 Rx, 100 samples (``Q R' > K``: a ragged split)."""
    full = RadarConfig.mmwcas(num_chirps=num_chirps)
    return dataclasses.replace(full, tx_positions=full.tx_positions[:5].copy(),
                               rx_positions=full.rx_positions[:7].copy(),
                               tdm_order=(4, 3, 2, 1, 0), num_samples=100)


RADARS = {"awr1843": lambda: RadarConfig.awr1843(num_chirps=3), "cascade_cut": _cascade_cut}


def _factors(radar, P, moving, seed=0, quantum=None):
    """Random factors; Tx and Rx legs of similar length like real paths.

    ``quantum``: round delays to multiples of it [s] (exact float32 sums).
    """
    rng = np.random.default_rng(seed)
    T, R = radar.num_tx, radar.num_rx
    c = rng.normal(size=P) + 1j * rng.normal(size=P)
    g_t = rng.uniform(0.2, 1.5, (T, P))
    g_r = rng.uniform(0.2, 1.5, (R, P))
    leg = rng.uniform(1e-9, 0.45 * 2 * radar.max_range / C, P)
    tau_t = leg + rng.uniform(-3e-11, 3e-11, (T, P))
    tau_r = leg + rng.uniform(-3e-11, 3e-11, (R, P))
    if quantum:
        tau_t, tau_r = (np.round(x / quantum) * quantum for x in (tau_t, tau_r))
    rho = rng.uniform(-2e-7, 2e-7, P) if moving else None
    return [c, g_t, tau_t, g_r, tau_r, rho]


def _expand(c, g_t, tau_t, g_r, tau_r, rho):
    a = c[None, None, :] * g_t[:, None, :] * g_r[None, :, :]
    tau = tau_t[:, None, :] + tau_r[None, :, :]
    return a, tau, None if rho is None else np.broadcast_to(rho, a.shape)


def _rel(x, ref):
    return float(np.abs(x - ref).max() / np.abs(ref).max())


# --------------------------------------------------------------- forward
@pytest.mark.parametrize("moving", [False, True], ids=["static", "moving"])
@pytest.mark.parametrize("name", sorted(RADARS))
def test_01_matches_expanded_synthesis(name, moving):
    radar = RADARS[name]()
    f = _factors(radar, 60, moving)
    s = synthesize_adc_factorised(radar, *f)
    assert s.shape == radar.adc_shape and s.dtype == np.complex64
    exact = synthesize_adc_basic(radar, *_expand(*f))          # complex128 reference twin
    fast = synthesize_adc(radar, *_expand(*f))                  # the expanded fast path
    assert _rel(s, exact) < 1e-5
    # the expanded fast synthesiser itself is accurate to ~5e-5 (float32 recurrences)
    assert _rel(s, fast) < 1e-4
    if not moving:
        assert np.array_equal(s[:, :, 0], s[:, :, -1])


def test_02_chunking_and_single_path_invariance():
    radar = _cascade_cut()
    f = _factors(radar, 101, True, seed=1)
    x = check_factor_inputs(radar, *f)
    one = FactorisedSynthesis(radar, x).forward()
    many = FactorisedSynthesis(radar, x, chunk_bytes=1).forward()     # 32-path chunks
    assert _rel(many, one) < 1e-6
    # the sum over paths is linear: two halves add up
    h = [[None if v is None else v[..., sl] for v in f] for sl in (slice(0, 50), slice(50, None))]
    parts = synthesize_adc_factorised(radar, *h[0]) + synthesize_adc_factorised(radar, *h[1])
    assert _rel(parts, one) < 1e-5


def test_03_point_target_phase_by_hand():
    """One path, one Tx / Rx leg each: phase 2 pi (f0 + S t_k)(tau_t + tau_r)."""
    radar = RadarConfig.awr1843()
    T, R = radar.num_tx, radar.num_rx
    tau_t, tau_r = np.full((T, 1), 2.0 / C), np.full((R, 1), 2.1 / C)
    s = synthesize_adc_factorised(radar, np.array([0.5 - 0.5j]), np.ones((T, 1)), tau_t,
                                  np.full((R, 1), 2.0), tau_r)
    tk = radar.sample_times()
    expected = (0.5 - 0.5j) * 2.0 * np.exp(2j * np.pi * (radar.start_frequency + radar.slope * tk)
                                           * (4.1 / C))
    assert np.abs(s[1, 2, 0] - expected).max() < 1e-5


# --------------------------------------------------------------- adjoints
def _loss(radar, target, args):
    """Real loss ``sum |s - target|^2`` on the complex128 reference twin."""
    return float(np.sum(np.abs(synthesize_adc_basic(radar, *_expand(*args)) - target) ** 2))


#: central-difference steps: amplitudes / gains ~1, delays 1e-14 s (0.005 rad of
#: carrier phase), delay rates 1e-12 (0.02 rad over the frame)
STEPS = dict(c=1e-6, g_t=1e-6, tau_t=1e-14, g_r=1e-6, tau_r=1e-14, tau_rate=1e-12)


@pytest.mark.parametrize("moving", [False, True], ids=["static", "moving"])
@pytest.mark.parametrize("synthesis", ["exact", "nufft"])
def test_04_vjp_matches_central_differences(moving, synthesis):
    """VJP of the exact twin and of the NUFFT synthesiser vs central
    differences of the complex128 expanded reference (independent of both)."""
    from sionna_mmir.fmcw.synthesize_nufft import NufftSynthesis

    radar = RadarConfig.awr1843(num_chirps=3)
    f = _factors(radar, 4, moving, seed=2)
    rng = np.random.default_rng(1)
    target = 0.7 * synthesize_adc_basic(radar, *_expand(*f)) + rng.normal(size=radar.adc_shape)
    s = synthesize_adc_factorised(radar, *f)
    if synthesis == "exact":
        grads = synthesize_adc_factorised_vjp(radar, 2 * (s - target), *f)
    else:
        grads = NufftSynthesis(radar, check_factor_inputs(radar, *f)).vjp(2 * (s - target))
    assert (grads["tau_rate"] is None) == (not moving)
    worst = 0.0
    for k, name in enumerate(NAMES):
        if f[k] is None:
            continue
        idxs = [(0,), (3,)] if f[k].ndim == 1 else [(0, 0), (2, 3)]
        units = (1.0, 1j) if name == "c" else (1.0,)
        for idx in idxs:
            for unit in units:
                vals = []
                for sign in (1, -1):
                    args = [None if v is None else v.copy() for v in f]
                    args[k][idx] += sign * STEPS[name] * unit
                    vals.append(_loss(radar, target, args))
                fd = (vals[0] - vals[1]) / (2 * STEPS[name])
                g = grads[name][idx]
                ad = g.imag if unit == 1j else np.real(g)
                err = abs(ad - fd) / abs(fd)
                worst = max(worst, err)
                assert err < 0.02, (name, idx, unit, ad, fd)
    # measured ~1e-5 (exact) / 1.1e-3 (NUFFT: float32, eps 1e-5, on the smallest entry)
    assert worst < (1e-3 if synthesis == "exact" else 5e-3)


@pytest.mark.parametrize("moving", [False, True], ids=["static", "moving"])
def test_05_jvp_matches_differences_and_vjp(moving):
    radar = _cascade_cut(num_chirps=2)
    f = _factors(radar, 7, moving, seed=4)
    rng = np.random.default_rng(9)
    scale = dict(c=1, g_t=1, tau_t=1e-14, g_r=1, tau_r=1e-14, tau_rate=1e-12)
    tang = [None if v is None else rng.normal(size=v.shape) * scale[n] for v, n in zip(f, NAMES)]
    tang[0] = tang[0] + 1j * rng.normal(size=tang[0].shape)
    synth = FactorisedSynthesis(radar, check_factor_inputs(radar, *f))
    ds = synth.jvp(*tang)
    h = 1e-3
    plus = [None if v is None else v + h * t for v, t in zip(f, tang)]
    minus = [None if v is None else v - h * t for v, t in zip(f, tang)]
    fd = (synthesize_adc_basic(radar, *_expand(*plus))
          - synthesize_adc_basic(radar, *_expand(*minus))) / (2 * h)
    assert _rel(ds, fd) < 1e-4
    # <G, J t> == <J^T G, t>
    G = rng.normal(size=radar.adc_shape) + 1j * rng.normal(size=radar.adc_shape)
    g = synth.vjp(G)
    lhs = np.sum(np.real(np.conj(G) * ds))
    rhs = sum(np.sum(np.real(np.conj(g[n]) * t)) for n, t in zip(NAMES, tang) if t is not None)
    assert abs(lhs - rhs) <= 1e-5 * abs(lhs)


# --------------------------------------------------------------- Dr.Jit node
def _drjit():
    sionna_mmir.init_backend()
    import drjit as dr
    import mitsuba as mi
    return dr, mi


def _dr_factors(f, mi, dr):
    """Flat ``mi.Float`` factors with gradients enabled."""
    c, g_t, tau_t, g_r, tau_r, rho = f
    flat = dict(c_re=c.real, c_im=c.imag, g_t=g_t.ravel(), tau_t=tau_t.ravel(),
                g_r=g_r.ravel(), tau_r=tau_r.ravel(), rate=rho)
    out = {}
    for k, v in flat.items():
        if v is not None:
            out[k] = mi.Float(np.asarray(v, np.float32))
            dr.enable_grad(out[k])
        else:
            out[k] = None
    return out


def _projection_loss(dr, mi, adc, W):
    """A real loss mixing a random projection and the power of the ADC."""
    wr, wi = (mi.Float(x.astype(np.float32).ravel()) for x in (W.real, W.imag))
    re, im = adc.real.array, adc.imag.array
    return dr.sum(re * wr + im * wi) + 1e-3 * dr.sum(re * re + im * im)


@pytest.mark.parametrize("moving", [False, True], ids=["static", "moving"])
def test_06_drjit_gradients_equal_expanded_path(moving):
    """dr.backward through the factorised node == through gather + expanded node."""
    dr, mi = _drjit()
    from sionna_mmir.fmcw.drjit_factorised import synthesize_adc_factorised_drjit
    from sionna_mmir.paths.radar_paths import PathFactors

    radar = _cascade_cut(num_chirps=3)
    T, R, P = radar.num_tx, radar.num_rx, 9
    # delays on a 2^-40 s grid: tau_t + tau_r is exact in float32 on both routes
    f = _factors(radar, P, moving, seed=6, quantum=2.0 ** -40)
    # float32-representable values: both routes see exactly the same inputs
    f = [None if v is None else (v.astype(np.complex64) if np.iscomplexobj(v)
                                 else v.astype(np.float32)).astype(v.dtype) for v in f]
    W = np.random.default_rng(3).normal(size=radar.adc_shape) * (1 + 0.3j)
    grads = []
    for route in ("factorised", "expanded"):
        x = _dr_factors(f, mi, dr)
        if route == "factorised":
            adc = synthesize_adc_factorised_drjit(radar, *x.values())
        else:
            pf = PathFactors(*x.values(), shape=(T, R, P))
            shape = (T, R, P)
            a_re, a_im, tau = (mi.TensorXf(pf.expand(n), shape) for n in ("a_re", "a_im", "tau"))
            rate = mi.TensorXf(pf.expand("tau_rate"), shape) if moving else None
            adc = synthesize_adc(radar, (a_re, a_im), tau, rate)
        dr.backward(_projection_loss(dr, mi, adc, W))
        grads.append({k: np.array(dr.grad(v)) for k, v in x.items() if v is not None})
        if route == "factorised":
            values = np.array(adc.real) + 1j * np.array(adc.imag)
        else:
            assert _rel(values, np.array(adc.real) + 1j * np.array(adc.imag)) < 1e-4
    for k in grads[0]:
        g_f, g_e = grads[0][k], grads[1][k]
        assert np.abs(g_f - g_e).max() <= 1e-4 * np.abs(g_e).max(), k   # measured ~1e-5


@pytest.mark.parametrize("synthesis", ["exact", "nufft"])
def test_07_drjit_forward_mode_matches_reverse_mode(synthesis, monkeypatch):
    """JVP (exact matrix products) vs VJP of the AD node: exact twin to 1e-3 of
    the directional derivative; the NUFFT VJP (float32, ~1e-5 per entry) to
    1e-4 of the sum of |gradient| entries (the sum over entries cancels)."""
    dr, mi = _drjit()
    from sionna_mmir.fmcw import drjit_factorised
    from sionna_mmir.fmcw.drjit_factorised import synthesize_adc_factorised_drjit

    if synthesis == "exact":
        monkeypatch.setattr(drjit_factorised, "SYNTHESIS", FactorisedSynthesis)

    radar = _cascade_cut(num_chirps=2)
    f = _factors(radar, 5, True, seed=8)
    W = np.random.default_rng(4).normal(size=radar.adc_shape) * (1 - 0.5j)
    for name in ("tau_t", "g_r", "rate", "c_im"):
        x = _dr_factors(f, mi, dr)
        loss = _projection_loss(dr, mi, synthesize_adc_factorised_drjit(radar, *x.values()), W)
        dr.forward(x[name])                       # tangent 1 in every entry of one input
        fwd = float(np.array(dr.grad(loss))[0])
        x = _dr_factors(f, mi, dr)
        loss = _projection_loss(dr, mi, synthesize_adc_factorised_drjit(radar, *x.values()), W)
        dr.backward(loss)
        g = np.array(dr.grad(x[name]))
        rev = float(np.sum(g))
        tol = 1e-3 * abs(rev) if synthesis == "exact" else 1e-4 * float(np.abs(g).sum())
        assert abs(fwd - rev) <= tol, (name, fwd, rev)


# --------------------------------------------------------------- bad input
def _bad_case(radar, case):
    f = _factors(radar, 4, True)
    if case == "nan_c":
        f[0][1] = np.nan
        return f, "'c' holds NaN"
    if case == "inf_tau_t":
        f[2][0, 1] = np.inf
        return f, "'tau_t' holds NaN"
    if case == "nan_rate":
        f[5][2] = np.nan
        return f, "'tau_rate' holds NaN"
    if case == "shape_g_t":
        f[1] = f[1][:2]
        return f, "'g_t' must have shape"
    if case == "shape_tau_r":
        f[4] = f[4][:, :3]
        return f, "'tau_r' must have shape"
    if case == "shape_rate":
        f[5] = f[5][:2]
        return f, "'tau_rate' must have shape"
    if case == "complex_g_r":
        f[3] = f[3] + 1j
        return f, "'g_r' must be real"
    f[0] = f[0].reshape(2, 2)
    return f, "'c' must be"


@pytest.mark.parametrize("case", ["nan_c", "inf_tau_t", "nan_rate", "shape_g_t", "shape_tau_r",
                                  "shape_rate", "complex_g_r", "ndim_c"])
def test_08_bad_numpy_input_named(case):
    radar = RadarConfig.awr1843()
    f, match = _bad_case(radar, case)
    with pytest.raises(InputValueError, match=match):
        synthesize_adc_factorised(radar, *f)


@pytest.mark.parametrize("case", ["size_g_t", "size_rate", "nan_tau_r"])
def test_09_bad_drjit_input_named(case):
    dr, mi = _drjit()
    from sionna_mmir.fmcw.drjit_factorised import synthesize_adc_factorised_drjit

    radar = RadarConfig.awr1843()
    x = _dr_factors(_factors(radar, 4, True), mi, dr)
    if case == "size_g_t":
        x["g_t"] = mi.Float(np.ones(5, np.float32))
        match = "'g_t' has 5 entries"
    elif case == "size_rate":
        x["rate"] = mi.Float(np.ones(3, np.float32))
        match = "'rate' has 3 entries"
    else:
        v = np.array(x["tau_r"])
        v[3] = np.nan
        x["tau_r"] = mi.Float(v)
        match = "'tau_r' holds NaN"
    with pytest.raises(InputValueError, match=match):
        synthesize_adc_factorised_drjit(radar, *x.values())


# --------------------------------------------------------------- solver paths
@pytest.fixture(scope="module")
def plate_scene():
    from sionna_mmir.scene import load_scene

    radar = dataclasses.replace(RadarConfig.awr1843(num_chirps=4), num_samples=64)
    return load_scene({"wall": square_plate([2.0, 0.1, 0.0], 0.8, yaw_deg=10.0, subdiv=3),
                       "box": square_plate([3.0, -0.6, 0.2], 0.4, yaw_deg=-20.0, subdiv=2)},
                      materials={"wall": "concrete", "box": "metal"}, radar=radar)


@pytest.mark.parametrize("moving", [False, True], ids=["static", "moving"])
def test_10_solver_adc_same_as_expanded(plate_scene, moving):
    """Solver paths: factorised ADC == expanded ADC; lazy fields and power agree."""
    dr, mi = _drjit()
    from sionna_mmir.paths import RadarPathSolver, RadarPaths, to_numpy

    radar = plate_scene.radar
    opts = dict(num_rays=4000, max_depth=2, seed=3)
    if moving:
        opts["velocities"] = {"box": (1.2, 0.3, 0.0)}
    paths = RadarPathSolver()(plate_scene, **opts)
    assert paths.is_factorised and paths.num_paths > 100
    a, tau, rate = paths.numpy()
    assert (rate is None) == (not moving)
    ours = to_numpy(paths.adc(radar))
    ref = synthesize_adc(radar, a, tau, rate)
    assert _rel(ours, ref) < 1e-4
    # lazily expanded Dr.Jit fields agree with the NumPy expansion
    T, R, P = paths.shape
    np.testing.assert_allclose(np.array(paths.a_re).reshape(T, R, P), a.real, rtol=1e-5,
                               atol=1e-6 * np.abs(a).max())
    np.testing.assert_allclose(np.array(paths.tau).reshape(T, R, P), tau, rtol=1e-6)
    if moving:
        np.testing.assert_allclose(np.array(paths.tau_rate).reshape(T, R, P), rate, rtol=1e-6)
    # power without expansion
    p = float(np.array(paths.factors.power())[0])
    assert abs(p - np.sum(np.abs(a) ** 2)) <= 1e-5 * p
    # an expanded RadarPaths built from the arrays renders the same ADC, up to
    # its float32 delays tau_t + tau_r (~1e-3 rad of carrier phase; the
    # factorised node adds the legs in float64)
    flat = RadarPaths(paths.a_re, paths.a_im, paths.tau, paths.tau_rate, paths.shape,
                      paths.depth, paths.num_candidates)
    assert not flat.is_factorised
    assert _rel(to_numpy(flat.adc(radar)), ours) < 2e-3
    assert abs(float(np.array(flat.power())[0]) - p) <= 1e-5 * p


def test_11_solver_gradients_same_as_expanded(plate_scene):
    """Material / normal gradients of an ADC loss: factorised == expanded route."""
    dr, mi = _drjit()
    from sionna_mmir.paths import RadarPathSolver, RadarPaths

    radar = plate_scene.radar
    obj = plate_scene.mesh_objects["wall"]
    W = np.random.default_rng(2).normal(size=radar.adc_shape) * (1 + 0.4j)
    solver = RadarPathSolver()
    grads = []
    for route in ("factorised", "expanded"):
        mats = mi.TensorXf(np.array(obj.vertex_materials))
        dr.enable_grad(mats)
        obj.vertex_materials = mats
        paths = solver(plate_scene, num_rays=3000, max_depth=2, seed=4)
        if route == "expanded":
            paths = RadarPaths(paths.a_re, paths.a_im, paths.tau, paths.tau_rate, paths.shape,
                               paths.depth, paths.num_candidates)
        dr.backward(_projection_loss(dr, mi, paths.adc(radar), W))
        grads.append(np.array(dr.grad(mats)))
    obj.vertex_materials = mi.TensorXf(np.array(obj.vertex_materials))
    g_f, g_e = grads
    assert np.abs(g_e).max() > 0
    assert np.abs(g_f - g_e).max() <= 2e-3 * np.abs(g_e).max()


def test_12_setting_an_expanded_field_drops_the_factors(plate_scene):
    dr, mi = _drjit()
    from sionna_mmir.paths import RadarPathSolver

    paths = RadarPathSolver()(plate_scene, num_rays=1000, max_depth=1, seed=1)
    a, tau, _ = paths.numpy()
    paths.a_re = paths.a_re * 2.0
    assert not paths.is_factorised
    a2, tau2, _ = paths.numpy()
    np.testing.assert_allclose(a2.real, 2 * a.real, rtol=1e-5, atol=1e-7 * np.abs(a).max())
    np.testing.assert_allclose(a2.imag, a.imag, rtol=1e-5, atol=1e-7 * np.abs(a).max())
    np.testing.assert_allclose(tau2, tau, rtol=1e-6)


# --------------------------------------------------------------- NUFFT synthesis
@pytest.mark.parametrize("moving", [False, True], ids=["static", "moving"])
@pytest.mark.parametrize("name", sorted(RADARS))
def test_13_nufft_matches_exact_twin(name, moving):
    """The NUFFT synthesiser (the fast path) equals the exact matrix-product twin:
    forward and every VJP entry to 1e-4 of the largest (measured ~1e-5)."""
    from sionna_mmir.fmcw.synthesize_nufft import NufftSynthesis

    radar = RADARS[name]()
    x = check_factor_inputs(radar, *_factors(radar, 400, moving, seed=11))
    ref, fast = FactorisedSynthesis(radar, x), NufftSynthesis(radar, x)
    assert _rel(fast.forward(), ref.forward()) < 1e-4
    rng = np.random.default_rng(12)
    G = rng.normal(size=radar.adc_shape) + 1j * rng.normal(size=radar.adc_shape)
    g_ref, g_fast = ref.vjp(G), fast.vjp(G)
    for k in NAMES:
        if g_ref[k] is None:
            assert g_fast[k] is None
            continue
        assert g_fast[k].shape == g_ref[k].shape, k
        assert _rel(g_fast[k], g_ref[k]) < 1e-4, k


def test_14_nufft_point_target_closed_form():
    """One path, one pair: the NUFFT ADC is the closed-form beat tone
    ``c exp(j 2 pi (f0 + S t_k) tau)`` (independent of both synthesisers)."""
    from sionna_mmir.fmcw.synthesize_nufft import NufftSynthesis

    radar = RadarConfig.awr1843(num_chirps=1)
    T, R = radar.num_tx, radar.num_rx
    tau_t = np.full((T, 1), 3.1e-8) + 1e-12 * np.arange(T)[:, None]
    tau_r = np.full((R, 1), 2.9e-8) + 2e-12 * np.arange(R)[:, None]
    c = np.array([0.3 - 0.7j])
    x = check_factor_inputs(radar, c, np.ones((T, 1)), tau_t, np.ones((R, 1)), tau_r)
    s = NufftSynthesis(radar, x).forward()
    tk = radar.adc_start_time + np.arange(radar.num_samples) / radar.sample_rate
    tau = tau_t[:, None, :] + tau_r[None, :, :]                           # [T, R, 1]
    ref = c[0] * np.exp(2j * np.pi * (radar.start_frequency + radar.slope * tk) * tau)
    assert _rel(s[:, :, 0, :], ref) < 1e-4


@pytest.mark.parametrize("moving", [False, True], ids=["static", "moving"])
def test_15_pruning_drops_exactly_the_weak_paths(moving):
    """``PathFactors.adc(radar, min_rel_power)``: the ADC of the paths whose mean
    pair power ``|c|^2 mean g_t^2 mean g_r^2`` exceeds the threshold (chosen
    here independently), the dropped paths get no gradient, 0 keeps all."""
    dr, mi = _drjit()
    from sionna_mmir.paths.radar_paths import PathFactors

    radar = _cascade_cut(num_chirps=2)
    T, R = radar.num_tx, radar.num_rx
    f = _factors(radar, 40, moving, seed=21, quantum=2.0 ** -40)
    f[0][::3] *= 1e-5                                  # every third path: power ~1e-10 x
    # float32-representable values: both routes see exactly the same inputs
    f = [None if v is None else (v.astype(np.complex64) if np.iscomplexobj(v)
                                 else v.astype(np.float32)).astype(v.dtype) for v in f]
    c, g_t, tau_t, g_r, tau_r, rho = f
    power = np.abs(c) ** 2 * np.mean(g_t ** 2, axis=0) * np.mean(g_r ** 2, axis=0)
    keep = power > 1e-8 * power.max()
    assert 0 < keep.sum() < len(c)
    x = _dr_factors(f, mi, dr)
    pf = PathFactors(*x.values(), shape=(T, R, len(c)))
    adc = pf.adc(radar, 1e-8)
    got = np.array(adc.real) + 1j * np.array(adc.imag)
    sub = [None if v is None else v[..., keep] for v in f]
    assert _rel(got.reshape(radar.adc_shape), synthesize_adc_factorised(radar, *sub)) < 1e-4
    full = pf.adc(radar, 0.0)
    np.testing.assert_allclose(np.array(full.real).reshape(radar.adc_shape),
                               synthesize_adc_factorised(radar, *f).real, atol=1e-4 * np.abs(got).max())
    dr.backward(dr.sum(adc.real.array) + dr.sum(adc.imag.array))
    g = np.array(dr.grad(x["c_re"]))
    assert np.all(g[~keep] == 0) and np.all(g[keep] != 0)


@pytest.mark.parametrize("moving", [False, True], ids=["static", "moving"])
@pytest.mark.parametrize("synthesis", ["exact", "nufft"])
def test_16_vjp_without_delays_keeps_the_other_gradients(synthesis, moving):
    """``vjp(G, delays=False)`` (a fit that learns no geometry): the amplitude
    and gain gradients equal the full VJP of the exact twin (1e-4 of the
    largest), the delay gradients are zeros."""
    from sionna_mmir.fmcw.synthesize_nufft import NufftSynthesis

    radar = _cascade_cut(num_chirps=2)
    x = check_factor_inputs(radar, *_factors(radar, 300, moving, seed=31))
    rng = np.random.default_rng(32)
    G = rng.normal(size=radar.adc_shape) + 1j * rng.normal(size=radar.adc_shape)
    full = FactorisedSynthesis(radar, x).vjp(G)
    cls = FactorisedSynthesis if synthesis == "exact" else NufftSynthesis
    part = cls(radar, x).vjp(G, delays=False)
    for k in ("c", "g_t", "g_r"):
        assert _rel(part[k], full[k]) < 1e-4, k
    for k in ("tau_t", "tau_r") + (("tau_rate",) if moving else ()):
        assert np.all(part[k] == 0), k
        assert np.abs(full[k]).max() > 0, k


def test_17_drjit_node_skips_delay_gradients_only_when_unused():
    """The AD node gives the same gain and amplitude gradients whether or not
    the delays carry gradients; with delays enabled their gradients equal the
    exact twin's VJP (so skipping is decided by the graph, not guessed)."""
    dr, mi = _drjit()
    from sionna_mmir.fmcw.drjit_factorised import synthesize_adc_factorised_drjit

    radar = _cascade_cut(num_chirps=2)
    f = _factors(radar, 7, False, seed=33)
    W = np.random.default_rng(34).normal(size=radar.adc_shape) * (0.4 + 1j)
    grads = {}
    for case in ("all", "no_delays"):
        x = _dr_factors(f, mi, dr)
        if case == "no_delays":
            for k in ("tau_t", "tau_r"):
                x[k] = dr.detach(x[k])
        dr.backward(_projection_loss(dr, mi, synthesize_adc_factorised_drjit(radar, *x.values()), W))
        grads[case] = {k: np.array(dr.grad(v)) for k, v in x.items() if v is not None}
    for k in ("c_re", "c_im", "g_t", "g_r"):
        assert _rel(grads["no_delays"][k], grads["all"][k]) < 1e-5, k
    xf = check_factor_inputs(radar, *[None if v is None else
                                      (v.astype(np.complex64) if np.iscomplexobj(v)
                                       else v.astype(np.float32)).astype(v.dtype) for v in f])
    s = FactorisedSynthesis(radar, xf)
    ref = s.vjp(W + 2e-3 * s.forward())            # dL/dRe s + j dL/dIm s of the loss
    T, R = radar.num_tx, radar.num_rx
    assert _rel(grads["all"]["tau_t"].reshape(T, -1), ref["tau_t"]) < 1e-3
    assert np.all(grads["no_delays"]["tau_t"] == 0)
