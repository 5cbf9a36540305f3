"""Tests for :mod:`sionna_mmir.bsdf.fsd`: the Fraunhofer edge pattern against direct
quadrature, the ``sinc^2`` along-edge zeros, pdf normalisation, chi-square
goodness of fit of ``sample`` against ``pdf``, ``beta``, AD gradients and bad
input.

Histograms for the chi-square test are taken around the propagation direction
``d`` over ``(x, phi)`` with the warped polar coordinate
``x = log(1 + S (1 - cos theta)) / log(1 + 2 S)``, ``S = 1 / q0^2`` (as in
``tests/test_bsdf_lobes.py``), so that the narrow Lorentzian core is resolved.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, special

from sionna_mmir.bsdf import fsd
from sionna_mmir.bsdf._common import dr, mi

from helpers import sphere_chi2
from sionna_mmir.errors import InputValueError
from sionna_mmir.scene.edges import EdgeIndex, find_diffracting_edges

LAM = 3.9e-3
K = 2 * np.pi / LAM
S_BEAM = 3 * LAM
N_SAMPLES = 200_000
N_X, N_PHI, SUB = 20, 40, 10


# ---------------------------------------------------------------- helpers
def vec(a, cls=mi.Vector3f):
    a = np.asarray(a, dtype=np.float64).reshape(-1, 3).astype(np.float32)
    return cls(mi.Float(a[:, 0]), mi.Float(a[:, 1]), mi.Float(a[:, 2]))


def to_np(v):
    return np.stack([np.array(v.x), np.array(v.y), np.array(v.z)], axis=-1).astype(np.float64)


def basis(d):
    d = np.asarray(d, float) / np.linalg.norm(d)
    a = np.array([1.0, 0, 0]) if abs(d[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(d, a)
    u /= np.linalg.norm(u)
    return u, np.cross(d, u), d


def screen_edge(x, d, delta, angle_deg, tau0, tau1, depth=(0.0, 0.0), apex_depth=0.0):
    """World-space edge whose projection has direction ``angle``, signed distance
    ``delta`` from ``x`` (x on the opaque side for delta > 0) and along-edge
    coordinates ``tau0..tau1``; ``depth`` shifts the endpoints along ``d``."""
    u, v, dd = basis(d)
    a = np.radians(angle_deg)
    e = np.cos(a) * u + np.sin(a) * v
    n_in = -np.sin(a) * u + np.cos(a) * v            # opaque side
    foot = x - delta * n_in                           # delta = -n_in . P0
    p0 = foot + tau0 * e + depth[0] * dd
    p1 = foot + tau1 * e + depth[1] * dd
    apex = foot + 0.5 * (tau0 + tau1) * e + 0.05 * n_in + apex_depth * dd
    return p0, p1, apex


def edges_np(specs):
    p0, p1, ap = zip(*specs)
    return fsd.FsdEdges.from_numpy(np.array(p0), np.array(p1), np.array(ap))


def scalar_param(terms, key, j=0):
    return float(np.array(terms[j][key])[0])


D0 = np.array([0.0, 0.0, 1.0])
X0 = np.zeros(3)


def long_edge(delta, s=S_BEAM, angle=90.0):
    return edges_np([screen_edge(X0, D0, delta, angle, -20 * s, 20 * s)])


def dirs_from_q(d, q_uv):
    """Unit directions with transverse cosines ``q_uv [M, 2]`` in :func:`basis` (d)."""
    u, v, dd = basis(d)
    q = np.atleast_2d(q_uv)
    return q[:, :1] * u + q[:, 1:] * v + np.sqrt(1 - np.sum(q * q, 1))[:, None] * dd


def perp_spectrum_numeric(kappa, delta, s):
    """|int_delta^inf exp(-p^2/2s^2) exp(-j kappa p) dp|^2 by QAWO quadrature."""
    f = lambda p: np.exp(-p * p / (2 * s * s))  # noqa: E731
    b = delta + 12 * s
    re = integrate.quad(f, delta, b, weight="cos", wvar=kappa, limit=400)[0]
    im = integrate.quad(f, delta, b, weight="sin", wvar=kappa, limit=400)[0]
    return re * re + im * im


# ---------------------------------------------------------------- 1. Fraunhofer edge pattern
@pytest.mark.parametrize("delta_over_s", [0.0, 0.7])
def test_01_perpendicular_pattern_vs_quadrature(delta_over_s):
    """Along q_perp (q_par = 0): eval / cos = (k/2pi)^2 |F_perp(kq)|^2 l^2 / (pi s^2)."""
    s = 6 * LAM
    delta = delta_over_s * s
    edges = long_edge(delta, s)
    d, x = vec(D0), vec(X0, mi.Point3f)
    terms = fsd.edge_parameters(d, x, edges, LAM, s)
    l_vis = scalar_param(terms, "length")
    assert abs(l_vis - np.sqrt(np.pi) * s) < 1e-3 * s
    assert abs(scalar_param(terms, "delta") - delta) < 1e-4 * s
    q = np.array([0.0, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9])
    n_in = np.array([1.0, 0.0])  # edge along the screen's v axis for angle 90 deg
    wo = dirs_from_q(D0, q[:, None] * (-n_in[None, :]))
    val = np.array(fsd.eval(d, vec(wo), x, edges, LAM, s), dtype=np.float64)
    model = val / np.sqrt(1 - q * q)
    ref = np.array([(K / (2 * np.pi)) ** 2 * perp_spectrum_numeric(K * qq, delta, s)
                    * l_vis ** 2 / (np.pi * s * s) for qq in q])
    # value at q = 0 (matched by construction of q0) and the 1/q^2 tail (kappa s >= 11)
    assert abs(model[0] / ref[0] - 1) < 0.01, (model[0], ref[0])
    np.testing.assert_allclose(model[1:], ref[1:], rtol=0.03)
    slope = np.polyfit(np.log(q[2:]), np.log(model[2:]), 1)[0]
    assert abs(slope + 2) < 0.05, slope
    # exact delta = 0 closed form (Dawson) as a second, independent reference
    if delta_over_s == 0.0:
        kap = K * q[1:]
        exact = s * s * (np.pi / 2 * np.exp(-(kap * s) ** 2)
                         + 2 * special.dawsn(kap * s / np.sqrt(2)) ** 2)
        np.testing.assert_allclose(ref[1:] / exact / ((K / (2 * np.pi)) ** 2 * l_vis ** 2
                                                     / (np.pi * s * s)), 1, rtol=1e-6)


def test_02_weight_formula_and_q0():
    """w_full and q0 follow the documented closed forms (float64 SciPy reference)."""
    d, x = vec(D0), vec(X0, mi.Point3f)
    for dl in (-0.5, 0.0, 0.7, 2.0, 3.0):
        delta = dl * S_BEAM
        terms = fsd.edge_parameters(d, x, long_edge(delta), LAM, S_BEAM)
        xi = delta / (np.sqrt(2) * S_BEAM)
        l_vis = np.sqrt(np.pi) * S_BEAM
        w_ref = np.exp(-xi * xi) * special.erfc(xi) * (l_vis / S_BEAM) / (2 * np.sqrt(2 * np.pi))
        q0_ref = 1 / (K * S_BEAM * np.sqrt(np.pi / 2) * special.erfcx(xi))
        assert abs(scalar_param(terms, "w_full") / w_ref - 1) < 2e-4, dl
        assert abs(scalar_param(terms, "q0") / q0_ref - 1) < 2e-4, dl
    # far edge: w ~ exp(-delta^2/s^2) l / (2 pi delta)
    delta = 3 * S_BEAM
    w = scalar_param(fsd.edge_parameters(d, x, long_edge(delta), LAM, S_BEAM), "w_full")
    assert abs(w / (np.exp(-9) * np.sqrt(np.pi) * S_BEAM / (2 * np.pi * delta)) - 1) < 0.1


# ---------------------------------------------------------------- 3. sinc^2 along the edge
def test_03_sinc2_zeros_along_edge():
    s = S_BEAM
    edges = edges_np([screen_edge(X0, D0, 0.3 * s, 90.0, -1.2 * s, 1.5 * s)])
    d, x = vec(D0), vec(X0, mi.Point3f)
    l_vis = scalar_param(fsd.edge_parameters(d, x, edges, LAM, s), "length")
    l_ref = np.sqrt(np.pi) * s / 2 * (special.erf(1.5) - special.erf(-1.2))
    assert abs(l_vis / l_ref - 1) < 1e-4 and l_vis < 2.7 * s   # beam-clipped length
    n = np.arange(1, 5)
    zeros = 2 * np.pi * n / (K * l_vis)
    mids = 2 * np.pi * (n + 0.5) / (K * l_vis)
    assert mids[-1] < 0.95
    q = np.concatenate([[0.0], zeros, mids])
    wo = dirs_from_q(D0, np.stack([0 * q, q], 1))        # along the edge (screen v)
    val = np.array(fsd.eval(d, vec(wo), x, edges, LAM, s), dtype=np.float64)
    ratio = val / np.sqrt(1 - q * q) / val[0]
    assert np.all(ratio[1:5] < 1e-6), ratio[1:5]
    t = K * l_vis * mids / 2
    np.testing.assert_allclose(ratio[5:], (np.sin(t) / t) ** 2, rtol=2e-3)


# ---------------------------------------------------------------- chi-square machinery
def three_edges(d, x, s):
    return edges_np([
        screen_edge(x, d, 0.3 * s, 90.0, -20 * s, 20 * s, depth=(0.01, -0.02)),
        screen_edge(x, d, 0.8 * s, 20.0, -0.5 * s, 1.0 * s, depth=(0.0, 0.004)),
        screen_edge(x, d, 1.4 * s, -50.0, -1.0 * s, 0.3 * s, apex_depth=0.01),
    ])


CASES = {
    "one_edge": (D0, X0, lambda d, x, s: long_edge(0.2 * s, s, angle=30.0)),
    "three_edges": (np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0]),
                    np.array([0.1, 0.2, 0.3]), three_edges),
}


def chi2_fsd(d_np, x_np, edges, s, seed=1):
    """Return (p_value, integral of pdf over the sphere, fraction of valid samples)."""
    d, x = vec(d_np), vec(x_np, mi.Point3f)
    q0 = min(float(np.array(t["q0"])[0]) for t in fsd.edge_parameters(d, x, edges, LAM, s))
    scale = 1.0 / q0 ** 2
    rng = np.random.default_rng(seed)
    u = rng.random((N_SAMPLES, 3)).astype(np.float32)
    wo, p = fsd.sample(d, x, edges, LAM, s, mi.Float(u[:, 0]),
                       mi.Point2f(mi.Float(u[:, 1]), mi.Float(u[:, 2])))
    w, p = to_np(wo), np.array(p)
    sv, tv, m = basis(d_np)
    ok = p > 0
    pval, integral = sphere_chi2(w[ok], m, sv, tv, scale,
                                 lambda dirs: np.array(fsd.pdf(d, vec(dirs), x, edges, LAM, s)),
                                 N_X, N_PHI, SUB)
    return pval, integral, ok.mean()


# ---------------------------------------------------------------- 4. normalisation, eval/pdf
@pytest.mark.parametrize("case", sorted(CASES))
def test_04_pdf_normalised_and_eval_consistent(case):
    d_np, x_np, make = CASES[case]
    edges = make(d_np, x_np, S_BEAM)
    d, x = vec(d_np), vec(x_np, mi.Point3f)
    # quadrature of the pdf over the sphere (fine warped polar grid around d)
    nx, nphi = 600, 720
    scale = 1.0 / min(float(np.array(t["q0"])[0])
                      for t in fsd.edge_parameters(d, x, edges, LAM, S_BEAM)) ** 2
    L = np.log1p(2 * scale)
    X, P = np.meshgrid((np.arange(nx) + 0.5) / nx, (np.arange(nphi) + 0.5) / nphi * 2 * np.pi,
                       indexing="ij")
    C = 1 - np.expm1(X * L) / scale
    Sn = np.sqrt(np.clip(1 - C * C, 0, None))
    sv, tv, m = basis(d_np)
    dirs = (C[..., None] * m + Sn[..., None] * (np.cos(P)[..., None] * sv
                                                + np.sin(P)[..., None] * tv)).reshape(-1, 3)
    wo = vec(dirs)
    p = np.array(fsd.pdf(d, wo, x, edges, LAM, S_BEAM), dtype=np.float64)
    jac = L * np.exp(X * L).reshape(-1) / scale
    integral = np.sum(p * jac) / nx * 2 * np.pi / nphi
    assert abs(integral - 1) < 5e-3, integral            # 1 - (corner mass ~1e-3)
    assert np.all(p[C.reshape(-1) <= 0] == 0)             # forward hemisphere only
    for opacity in (1.0, 0.4):
        b = float(np.array(fsd.beta(d, x, edges, LAM, S_BEAM, opacity=opacity))[0])
        f = np.array(fsd.eval(d, wo, x, edges, LAM, S_BEAM, opacity=opacity), dtype=np.float64)
        np.testing.assert_allclose(f, b * p, rtol=1e-5, atol=1e-7 * p.max())


# ---------------------------------------------------------------- 5. chi-square of sample vs pdf
@pytest.mark.parametrize("case", sorted(CASES))
def test_05_chi2_sample_vs_pdf(case):
    d_np, x_np, make = CASES[case]
    edges = make(d_np, x_np, S_BEAM)
    pval, integral, valid_frac = chi2_fsd(d_np, x_np, edges, S_BEAM)
    assert pval > 0.01, pval
    assert abs(integral - 1) < 1e-2, integral
    assert abs(valid_frac - integral) < 5e-3, (valid_frac, integral)   # lost mass consistent


def test_06_sample_pdf_matches_pdf():
    d_np, x_np, make = CASES["three_edges"]
    edges = make(d_np, x_np, S_BEAM)
    d, x = vec(d_np), vec(x_np, mi.Point3f)
    u = np.random.default_rng(6).random((4096, 3)).astype(np.float32)
    wo, p = fsd.sample(d, x, edges, LAM, S_BEAM, mi.Float(u[:, 0]),
                       mi.Point2f(mi.Float(u[:, 1]), mi.Float(u[:, 2])))
    ref = np.array(fsd.pdf(d, wo, x, edges, LAM, S_BEAM))
    p = np.array(p)
    np.testing.assert_allclose(p[p > 0], ref[p > 0], rtol=1e-5)
    assert np.mean(p > 0) > 0.99
    np.testing.assert_allclose(np.linalg.norm(to_np(wo), axis=1), 1, atol=1e-5)
    assert np.all(to_np(wo) @ d_np > 0)


# ---------------------------------------------------------------- 7. beta
def test_07_beta_distance_opacity_cap_silhouette():
    d, x = vec(D0), vec(X0, mi.Point3f)

    def b(edges, opacity=1.0):
        return float(np.array(fsd.beta(d, x, edges, LAM, S_BEAM, opacity=opacity))[0])

    betas = [b(long_edge(dl * S_BEAM)) for dl in (0.0, 0.5, 1.0, 2.0, 4.0)]
    assert np.all(np.diff(betas) < 0) and betas[-1] < 1e-6 and betas[0] > 0.2, betas
    e = long_edge(0.5 * S_BEAM)
    np.testing.assert_allclose([b(e, o) for o in (0.0, 0.25, 0.8)],
                               [0.0, 0.25 * b(e), 0.8 * b(e)], rtol=1e-6)
    # four edges through x: W > beta_max, beta capped
    many = edges_np([screen_edge(X0, D0, 0.0, a, -1, 1) for a in (0, 45, 90, 135)])
    assert abs(b(many) - fsd.BETA_MAX) < 1e-6
    # crease whose two faces project onto opposite sides: no silhouette, no diffraction
    p0, p1, ap = screen_edge(X0, D0, 0.0, 90.0, -1, 1)
    ap_other = 2 * (0.5 * (p0 + p1)) - ap
    crease = fsd.FsdEdges.from_numpy([p0], [p1], [ap], [ap_other])
    assert b(crease) == 0.0
    # invalid slots and edges parallel to d contribute nothing
    assert b(fsd.FsdEdges.from_numpy([p0], [p1], [ap], valid=[False])) == 0.0
    par = fsd.FsdEdges.from_numpy([[0.001, 0, -0.1]], [[0.001, 0, 0.1]], [[0.0, 0, 0]])
    assert b(par) == 0.0


# ---------------------------------------------------------------- 8. AD gradients
N_GRAD = 64


def _grad_dirs(d_np, rng):
    q = rng.normal(size=(N_GRAD, 2)) * 0.15
    q = q[np.linalg.norm(q, axis=1) < 0.8]
    return dirs_from_q(d_np, q)


def test_08_grad_edge_endpoint_and_opacity():
    rng = np.random.default_rng(8)
    d_np, x_np = CASES["three_edges"][0], CASES["three_edges"][1]
    s = S_BEAM
    p0, p1, ap = screen_edge(x_np, d_np, 0.4 * s, 70.0, -0.6 * s, 0.9 * s, depth=(0.003, 0.0))
    wo_np = _grad_dirs(d_np, rng)
    n = len(wo_np)
    wo, d, x = vec(wo_np), vec(d_np), vec(x_np, mi.Point3f)

    def f(coord, opacity=0.7):
        pa = mi.Point3f(coord, dr.full(mi.Float, p0[1], n), dr.full(mi.Float, p0[2], n))
        apex = vec(np.tile(ap, (n, 1)), mi.Point3f)
        e = fsd.FsdEdges(pa, vec(np.tile(p1, (n, 1)), mi.Point3f), apex, apex,
                         dr.full(mi.Bool, True, n), 1)
        return fsd.eval(d, wo, x, e, LAM, s, opacity=opacity)

    c = dr.full(mi.Float, p0[0], n)
    dr.enable_grad(c)
    y = f(c)
    dr.backward(dr.sum(y))
    g = np.array(dr.grad(c), dtype=np.float64)
    h = 2e-3 * s
    fd = (np.array(f(mi.Float(np.full(n, p0[0] + h, np.float32))), dtype=np.float64)
          - np.array(f(mi.Float(np.full(n, p0[0] - h, np.float32))), dtype=np.float64)) \
        / (np.float32(p0[0] + h) - np.float32(p0[0] - h)).astype(np.float64)
    scale = np.abs(fd).max()
    assert scale > 0
    err = np.abs(g - fd) / np.maximum(np.abs(fd), 1e-2 * scale)
    assert err.max() < 1e-2, err.max()

    op = dr.full(mi.Float, 0.7, n)
    dr.enable_grad(op)
    y = f(mi.Float(np.full(n, p0[0], np.float32)), op)
    dr.backward(dr.sum(y))
    g = np.array(dr.grad(op), dtype=np.float64)
    fd = (np.array(f(mi.Float(np.full(n, p0[0], np.float32)), 0.71), dtype=np.float64)
          - np.array(f(mi.Float(np.full(n, p0[0], np.float32)), 0.69), dtype=np.float64)) / 0.02
    np.testing.assert_allclose(g, fd, rtol=1e-2, atol=1e-3 * np.abs(fd).max())


def test_09_mesh_edges_to_lobe_with_vertex_gradients():
    """EdgeSet + EdgeIndex -> FsdEdges.from_vertices -> eval; gradients reach the vertices."""
    v = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    es = find_diffracting_edges(v, f)
    hit = np.array([[0.095, 0.05, 0.0]])               # 5 mm from the x = 0.1 edge
    idx, valid = EdgeIndex(es).query(hit, radius=0.03, max_edges=4)
    assert valid.sum() == 1 and np.allclose(es.p0[idx[0, 0]][0], 0.1)
    d_np = np.array([0.0, 0.0, -1.0])
    wo_np = dirs_from_q(d_np, np.array([[0.05, 0.0], [-0.05, 0.0], [0.0, 0.2], [0.3, 0.01]]))
    verts = mi.Float(v.astype(np.float32).ravel())
    dr.enable_grad(verts)
    edges = fsd.FsdEdges.from_vertices(verts, es, idx, valid)
    val = fsd.eval(vec(d_np), vec(wo_np), vec(hit, mi.Point3f), edges, LAM, S_BEAM)
    assert np.all(np.array(val)[:2] > 0)
    dr.backward(dr.sum(val))
    g = np.array(dr.grad(verts)).reshape(-1, 3)
    assert np.all(np.isfinite(g)) and np.abs(g[1:3, 0]).max() > 0   # x of the edge vertices

    def total(shift):
        vv = v.copy()
        vv[1:3, 0] += shift
        e = fsd.FsdEdges.from_vertices(mi.Float(vv.astype(np.float32).ravel()), es, idx, valid)
        return float(np.sum(np.array(fsd.eval(vec(d_np), vec(wo_np), vec(hit, mi.Point3f), e,
                                              LAM, S_BEAM), dtype=np.float64)))

    h = 2e-5
    fd = (total(h) - total(-h)) / (2 * h)
    assert abs((g[1, 0] + g[2, 0]) / fd - 1) < 1e-2, (g[1:3, 0], fd)


# ---------------------------------------------------------------- 10. bad input
def test_10_bad_input_raises():
    p0, p1, ap = screen_edge(X0, D0, 0.0, 90.0, -1, 1)
    d, x, wo = vec(D0), vec(X0, mi.Point3f), vec(D0)
    with pytest.raises(InputValueError, match="NaN"):
        fsd.FsdEdges.from_numpy([[np.nan, 0, 0]], [p1], [ap])
    with pytest.raises(InputValueError):
        fsd.FsdEdges.from_numpy(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    good = fsd.FsdEdges.from_numpy([p0], [p1], [ap])
    nan_edges = good._replace(p1=mi.Point3f(np.nan, 0.0, 0.0))
    with pytest.raises(InputValueError, match="NaN"):
        fsd.eval(d, wo, x, nan_edges, LAM)
    with pytest.raises(InputValueError, match="NaN"):
        fsd.pdf(d, wo, vec([np.nan, 0, 0], mi.Point3f), good, LAM)
    empty = fsd.FsdEdges(mi.Point3f(), mi.Point3f(), mi.Point3f(), mi.Point3f(), mi.Bool(), 1)
    with pytest.raises(InputValueError, match="empty"):
        fsd.eval(d, wo, x, empty, LAM)
    with pytest.raises(InputValueError, match="empty"):
        fsd.sample(d, x, good._replace(k=0), LAM, None, mi.Float(0.5), mi.Point2f(0.5, 0.5))
    with pytest.raises(InputValueError):
        fsd.beta(d, x, good, -LAM)
    with pytest.raises(InputValueError):
        fsd.eval(d, wo, x, good, LAM, s=float("nan"))


# ---------------------------------------------------------------- 11. [N, K] layout
def test_11_per_point_rows_match_broadcast_row():
    """N rows of K edges (one row per query point) == one row broadcast; Dr.Jit lam / s."""
    d_np, x_np, make = CASES["three_edges"]
    one = make(d_np, x_np, S_BEAM)
    wo_np = _grad_dirs(d_np, np.random.default_rng(11))
    n = len(wo_np)

    def tile(p):
        a = to_np(p).reshape(1, 3, 3)
        return np.repeat(a, n, axis=0)

    rows = fsd.FsdEdges.from_numpy(tile(one.p0), tile(one.p1), tile(one.apex0), tile(one.apex1))
    assert rows.k == 3 and dr.width(rows.p0) == 3 * n
    d, x, wo = vec(np.tile(d_np, (n, 1))), vec(np.tile(x_np, (n, 1)), mi.Point3f), vec(wo_np)
    a = np.array(fsd.eval(d, wo, x, one, LAM, S_BEAM))
    b = np.array(fsd.eval(d, wo, x, rows, mi.Float(LAM), dr.full(mi.Float, S_BEAM, n)))
    np.testing.assert_allclose(a, b, rtol=1e-6)
    assert np.all(a > 0)
