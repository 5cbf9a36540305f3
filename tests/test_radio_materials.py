"""ITU-R P.2040 materials and Fresnel / slab physics against independent facts.

Reference values come from outside the code under test: ITU-R P.2040-3
Table 3 (as shipped in Sionna RT's own source, parsed at run time), hand
calculations, textbook identities (Born & Wolf Secs. 1.5-1.6: normal
incidence, Snell-law forms of the Fresnel equations, Brewster angle, power
balance) and an independent characteristic-matrix (transfer-matrix) solution
of the single-layer slab written out in this file.
"""
from __future__ import annotations

import ast
import importlib.util
import math
import pathlib

import numpy as np
import pytest

from sionna_mmir.errors import ConfigError
from sionna_mmir.radio_materials import (
    ITU_P2040_TABLE3,
    SURFACE_DEFAULTS,
    VERTEX_PARAMETER_NAMES,
    available_materials,
    complex_permittivity,
    default_vertex_parameters,
    energy_gate,
    fresnel_coefficients,
    itu_material,
    slab_coefficients,
)

C0 = 299_792_458.0
F77 = 77e9
LAM77 = C0 / F77


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def drm():
    """(mitsuba, drjit) after sionna_mmir's backend set-up."""
    from sionna_mmir.utils.backend import init_backend

    init_backend()
    import drjit as dr
    import mitsuba as mi

    return mi, dr


def _to_np(dr, z):
    """Dr.Jit Complex2f / Float -> numpy complex128 / float64."""
    if type(z).__name__.startswith("Complex"):
        return np.array(dr.real(z), dtype=np.float64) + 1j * np.array(dr.imag(z), dtype=np.float64)
    return np.array(z, dtype=np.float64)


def _sionna_itu_table():
    """``ITU_MATERIALS_PROPERTIES`` literal parsed from Sionna RT's source file."""
    spec = importlib.util.find_spec("sionna")
    if spec is None or not spec.submodule_search_locations:
        pytest.skip("sionna is not installed")
    path = pathlib.Path(spec.submodule_search_locations[0]) / "rt" / "radio_materials" / "itu.py"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "ITU_MATERIALS_PROPERTIES" for t in node.targets):
            return ast.literal_eval(node.value)
    pytest.skip("ITU_MATERIALS_PROPERTIES not found in Sionna's itu.py")


def _tmm_slab(cos_theta, eps, d, freq):
    """Single-layer slab by the characteristic-matrix method (Born & Wolf 1.6;
    Macleod, *Thin-Film Optical Filters*, ch. 2), written independently of the
    Airy / P.2040 closed form.

    Convention exp(+j w t), N = sqrt(eps) with Im <= 0.  Tilted optical
    admittances (units of the free-space admittance): s: N cos(theta_j),
    p: N / cos(theta_j).  Phase thickness delta = k0 d N cos(theta_1).
        [B, C]^T = [[cos D, j sin D / y1], [j y1 sin D, cos D]] [1, y0]^T
        r = (y0 B - C) / (y0 B + C),   t = 2 y0 / (y0 B + C)
    r, t are ratios of tangential E fields; with air on both sides t equals
    the total-field ratio.  Macleod's p-polarised r has the opposite sign of
    the P.2040 / Born & Wolf r_p (both conventions give r_p = r_s and
    r_p = -r_s at normal incidence, respectively), so -r_p is returned.
    """
    c = np.asarray(cos_theta, dtype=float)
    eps = np.asarray(eps, dtype=complex)
    sin2 = 1.0 - c * c
    n_cos = np.sqrt(eps - sin2)                       # N cos(theta_1), Im <= 0
    delta = 2 * np.pi * freq / C0 * d * n_cos
    # cos/sin of a strongly absorbing layer overflow; scale the matrix by
    # g = exp(-j delta) (r is a ratio and unchanged, t picks up 1/g):
    # g cos(delta) = (1 + e2) / 2, g j sin(delta) = (1 - e2) / 2, e2 = exp(-2 j delta).
    g = np.exp(-1j * delta)
    e2 = g * g
    cos_g, jsin_g = (1 + e2) / 2, (1 - e2) / 2
    out = {}
    for pol, y0, y1 in (("s", c, n_cos), ("p", 1.0 / c, eps / n_cos)):
        m11, m12 = cos_g, jsin_g / y1
        m21, m22 = jsin_g * y1, cos_g
        B = m11 + m12 * y0
        Cc = m21 + m22 * y0
        r = (y0 * B - Cc) / (y0 * B + Cc)
        t = 2 * y0 * g / (y0 * B + Cc)
        out[pol] = (r if pol == "s" else -r, t)
    return out["s"][0], out["p"][0], out["s"][1], out["p"][1]


def _angles(deg):
    return np.cos(np.deg2rad(np.asarray(deg, dtype=float)))


# --------------------------------------------------------------------------
# ITU-R P.2040 Table 3
# --------------------------------------------------------------------------
def test_01_table_rows_match_sionna_source():
    """Every row equals the same row of Sionna RT's ITU_MATERIALS_PROPERTIES."""
    sionna = _sionna_itu_table()
    for row in ITU_P2040_TABLE3:
        assert row.name in sionna, row.name
        key = (row.f_min_ghz, row.f_max_ghz)
        assert key in sionna[row.name], (row.name, key, list(sionna[row.name]))
        assert sionna[row.name][key] == pytest.approx((row.a, row.b, row.c, row.d), rel=1e-12), row
    names = {r.name for r in ITU_P2040_TABLE3}
    for required in ("concrete", "brick", "plasterboard", "wood", "glass", "ceiling_board",
                     "chipboard", "plywood", "marble", "floorboard", "metal",
                     "very_dry_ground", "medium_dry_ground", "wet_ground"):
        assert required in names


def test_02_table_spot_values_hard_coded():
    """Three rows read off ITU-R P.2040-3 Table 3 (identical in Sionna RT 2.2's
    itu.py and in an independent public re-implementation of the table)."""
    spot = {
        "concrete": (5.24, 0.0, 0.0462, 0.7822, (1.0, 100.0)),
        "glass": (6.31, 0.0, 0.0036, 1.3394, (0.1, 100.0)),
        "metal": (1.0, 0.0, 1.0e7, 0.0, (1.0, 100.0)),
    }
    for name, (a, b, c, d, band) in spot.items():
        m = itu_material(name, 30e9)
        assert m.valid_range_ghz == band
        assert m.eps_real == pytest.approx(a * 30.0 ** b, rel=1e-12)
        assert m.conductivity == pytest.approx(c * 30.0 ** d, rel=1e-12)


def test_03_concrete_eps_imag_at_77ghz_by_hand():
    """sigma = 0.0462 * 77^0.7822: ln 77 = 4.34381, x0.7822 = 3.39773,
    e^3.39773 = 29.897 -> sigma = 1.3812 S/m; eps'' = 17.98 sigma / 77 = 0.3225."""
    m = itu_material("concrete", F77)
    assert m.eps_real == pytest.approx(5.24, rel=1e-12)
    assert m.conductivity == pytest.approx(1.3812, rel=2e-4)
    assert m.eps_imag == pytest.approx(0.3225, rel=1e-3)
    assert m.eps_imag == pytest.approx(17.98 * m.conductivity / 77.0, rel=1e-3)
    assert m.eps_r == complex(m.eps_real, -m.eps_imag)


@pytest.mark.parametrize("name,band", [("brick", "1-40 GHz"), ("marble", "1-60 GHz"),
                                       ("plywood", "1-40 GHz"), ("wet_ground", "1-10 GHz")])
def test_04_out_of_band_raises_config_error(name, band):
    with pytest.raises(ConfigError) as info:
        itu_material(name, F77)
    msg = str(info.value)
    assert name in msg and "77 GHz" in msg and band in msg
    m = itu_material(name, F77, allow_out_of_band=True)
    assert not m.in_band and np.isfinite(m.eps_real) and m.eps_imag >= 0


def test_05_available_materials_at_77ghz_and_unknown_names():
    # P.2040-3 Table 3 ranges containing 77 GHz (1-100, 0.001-100, 0.1-100, 50-100 GHz)
    expected = {"concrete", "plasterboard", "wood", "glass", "ceiling_board", "chipboard",
                "floorboard", "metal"}
    assert set(available_materials(F77)) == expected
    assert "brick" in available_materials(28e9) and "floorboard" not in available_materials(28e9)
    assert itu_material("Ceiling board", F77).name == "ceiling_board"
    with pytest.raises(ConfigError, match="unobtainium"):
        itu_material("unobtainium", F77)
    with pytest.raises(ConfigError):
        itu_material("concrete", -1.0)


def test_06_default_vertex_parameters():
    for name in available_materials(F77):
        p = default_vertex_parameters(name, F77)
        m = itu_material(name, F77)
        s = SURFACE_DEFAULTS[name]
        assert p.shape == (len(VERTEX_PARAMETER_NAMES),) == (6,) and p.dtype == np.float64
        np.testing.assert_array_equal(p, [m.eps_real, m.eps_imag, s.sigma_h, s.l_c, s.tau,
                                          s.thickness])
        assert p[0] >= 1.0 and p[1] >= 0 and p[2] >= 0 and p[3] > 0 and 0 <= p[4] <= 1 and p[5] > 0
    assert default_vertex_parameters("glass", F77)[5] == pytest.approx(0.006)
    assert default_vertex_parameters("concrete", F77)[5] == pytest.approx(0.2)
    with pytest.raises(ConfigError, match="brick"):
        default_vertex_parameters("brick", F77)


# --------------------------------------------------------------------------
# single interface
# --------------------------------------------------------------------------
EPS_SET = np.array([4.0, 2.73 - 0.1j, 5.24 - 0.3225j, 6.31 - 0.2826j, 30.0 - 10.0j])


def test_07_normal_incidence():
    """|r| = |(1 - n)/(1 + n)|; P.2040/Born & Wolf convention r_p = -r_s, t = 2/(1 + n)."""
    n = np.sqrt(EPS_SET)
    fc = fresnel_coefficients(np.ones_like(n.real), EPS_SET)
    np.testing.assert_allclose(fc.r_s, (1 - n) / (1 + n), rtol=1e-12)
    np.testing.assert_allclose(fc.r_p, -(1 - n) / (1 + n), rtol=1e-12)
    np.testing.assert_allclose(np.abs(fc.r_s), np.abs((1 - n) / (1 + n)), rtol=1e-12)
    np.testing.assert_allclose(fc.t_s, 2 / (1 + n), rtol=1e-12)
    np.testing.assert_allclose(fc.t_p, 2 / (1 + n), rtol=1e-12)


def test_08_snell_forms_lossless():
    """Born & Wolf 1.5 (21): r_s = -sin(ti - tt)/sin(ti + tt), r_p = tan(ti - tt)/tan(ti + tt),
    t_s = 2 sin(tt) cos(ti) / sin(ti + tt), t_p = 2 sin(tt) cos(ti) / (sin(ti + tt) cos(ti - tt))."""
    ti = np.deg2rad(np.linspace(1, 89, 30))
    for eps in (2.0, 4.0, 6.31):
        tt = np.arcsin(np.sin(ti) / np.sqrt(eps))
        fc = fresnel_coefficients(np.cos(ti), eps + 0j)
        np.testing.assert_allclose(fc.r_s, -np.sin(ti - tt) / np.sin(ti + tt), atol=1e-12)
        np.testing.assert_allclose(fc.r_p, np.tan(ti - tt) / np.tan(ti + tt), atol=1e-12)
        np.testing.assert_allclose(fc.t_s, 2 * np.sin(tt) * np.cos(ti) / np.sin(ti + tt), atol=1e-12)
        np.testing.assert_allclose(
            fc.t_p, 2 * np.sin(tt) * np.cos(ti) / (np.sin(ti + tt) * np.cos(ti - tt)), atol=1e-12)


def test_09_brewster_angle(drm):
    mi, dr = drm
    for eps in (2.73, 4.0, 6.31):
        c_b = math.cos(math.atan(math.sqrt(eps)))
        assert abs(fresnel_coefficients(c_b, eps + 0j).r_p) < 1e-12
        r_p_dr = fresnel_coefficients(mi.Float(c_b), mi.Complex2f(eps, 0.0)).r_p
        assert np.abs(_to_np(dr, r_p_dr)).max() < 2e-6
        # on either side of Brewster r_p changes sign (real for lossless media)
        lo = fresnel_coefficients(math.cos(math.atan(math.sqrt(eps)) - 0.05), eps + 0j).r_p
        hi = fresnel_coefficients(math.cos(math.atan(math.sqrt(eps)) + 0.05), eps + 0j).r_p
        assert lo.real > 0 > hi.real


def test_10_grazing_and_pec_limits():
    for c in (1e-3, 1e-4):
        fc = fresnel_coefficients(c, EPS_SET)
        assert np.all(np.abs(fc.r_s) > 1 - 30 * c) and np.all(np.abs(fc.r_p) > 1 - 30 * c)
    cos = _angles([0, 30, 60, 80])
    for big in (1e6, 1e9):
        fc = fresnel_coefficients(cos, 1.0 - 1j * big)
        tol = 10 / math.sqrt(big)
        np.testing.assert_allclose(np.abs(fc.r_s), 1.0, atol=tol)
        np.testing.assert_allclose(np.abs(fc.r_p), 1.0, atol=tol)
        np.testing.assert_allclose(fc.r_s, -1.0, atol=tol)
    metal = itu_material("metal", F77).eps_r
    assert np.all(np.abs(fresnel_coefficients(cos, metal).r_s) > 0.995)


def test_11_interface_power_balance_lossless():
    """|r|^2 + Re(N cos tt)/cos ti |t|^2 = 1 for both polarisations (Born & Wolf 1.5.3)."""
    cos = _angles(np.linspace(0, 89.9, 50))
    for eps in (1.5, 4.0, 9.0, 30.0):
        fc = fresnel_coefficients(cos, eps + 0j)
        factor = np.sqrt(eps - (1 - cos ** 2)).real / cos
        np.testing.assert_allclose(np.abs(fc.r_s) ** 2 + factor * np.abs(fc.t_s) ** 2, 1, atol=1e-12)
        np.testing.assert_allclose(np.abs(fc.r_p) ** 2 + factor * np.abs(fc.t_p) ** 2, 1, atol=1e-12)
    # lossy: reflected + transmitted power < incident
    fc = fresnel_coefficients(cos, 5.24 - 0.3225j)
    factor = np.sqrt(5.24 - 0.3225j - (1 - cos ** 2)).real / cos
    assert np.all(np.abs(fc.r_s) ** 2 + factor * np.abs(fc.t_s) ** 2 <= 1 + 1e-12)


# --------------------------------------------------------------------------
# slab
# --------------------------------------------------------------------------
def test_12_slab_thin_and_half_wave_limits():
    cos = _angles([0, 20, 45, 70, 85])
    for eps in EPS_SET:
        sc = slab_coefficients(cos, eps, 0.0, F77)
        np.testing.assert_allclose(np.abs(sc.r_s), 0, atol=1e-15)
        np.testing.assert_allclose(np.abs(sc.r_p), 0, atol=1e-15)
        np.testing.assert_allclose(sc.t_s, 1, atol=1e-15)
        np.testing.assert_allclose(sc.t_p, 1, atol=1e-15)
        sc = slab_coefficients(cos, eps, 1e-11, F77)
        assert np.all(np.abs(sc.r_s) < 1e-5) and np.all(np.abs(np.abs(sc.t_s) - 1) < 1e-5)
    # lossless slab half a wavelength thick in the medium, normal incidence: transparent
    for eps in (2.73, 4.0, 6.31):
        d = LAM77 / (2 * math.sqrt(eps))
        for m in (1, 2, 3):
            sc = slab_coefficients(1.0, eps + 0j, m * d, F77)
            assert abs(sc.r_s) < 1e-12 and abs(sc.r_p) < 1e-12
            assert abs(abs(sc.t_s) - 1) < 1e-12
        # quarter-wave layer: |R|^2 = 4 r^2 / (1 + r^2)^2 (Born & Wolf 1.6.4)
        r = (1 - math.sqrt(eps)) / (1 + math.sqrt(eps))
        sc = slab_coefficients(1.0, eps + 0j, d / 2, F77)
        assert abs(sc.r_s) ** 2 == pytest.approx(4 * r * r / (1 + r * r) ** 2, rel=1e-12)


def test_13_thick_lossy_slab_converges_to_interface():
    cos = _angles([0, 30, 60, 80])
    for eps in (5.24 - 0.3225j, 6.31 - 0.2826j, 2.0 - 0.5j):
        fc = fresnel_coefficients(cos, eps)
        sc = slab_coefficients(cos, eps, 2.0, F77)
        np.testing.assert_allclose(sc.r_s, fc.r_s, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(sc.r_p, fc.r_p, rtol=1e-9, atol=1e-12)
        assert np.all(np.abs(sc.t_s) < 1e-9) and np.all(np.abs(sc.t_p) < 1e-9)


def test_14_lossless_slab_energy_conservation():
    cos = _angles(np.linspace(0, 89, 40))[:, None]
    d = np.array([1e-4, 1e-3, 3e-3, 6e-3, 0.02, 0.2])[None, :]
    for eps in (1.48, 2.73, 6.31, 20.0):
        sc = slab_coefficients(cos, eps + 0j, d, F77)
        np.testing.assert_allclose(np.abs(sc.r_s) ** 2 + np.abs(sc.t_s) ** 2, 1, atol=1e-12)
        np.testing.assert_allclose(np.abs(sc.r_p) ** 2 + np.abs(sc.t_p) ** 2, 1, atol=1e-12)
    sc = slab_coefficients(cos, 5.24 - 0.3225j, d, F77)
    assert np.all(np.abs(sc.r_s) ** 2 + np.abs(sc.t_s) ** 2 < 1)


def test_15_slab_matches_transfer_matrix():
    """P.2040-3 eqs. (43)-(44) vs the characteristic-matrix method (< 1 %)."""
    rng = np.random.default_rng(7)
    cos = _angles([0, 10, 25, 40, 55, 70, 85])[:, None, None]
    d = np.array([1e-4, 8e-4, 2.5e-3, 6e-3, 0.0125, 0.03, 0.2])[None, :, None]
    eps = np.concatenate([[4.0, 6.31 - 0.2826j, 5.24 - 0.3225j, 1.0 - 2.3e6j],
                          rng.uniform(1.2, 12, 6) - 1j * rng.uniform(0, 2, 6)])[None, None, :]
    for freq in (F77, 60e9, 28e9):
        sc = slab_coefficients(cos, eps, d, freq)
        ref = _tmm_slab(cos, eps, d, freq)
        for got, want in zip(sc, ref):
            err = np.abs(got - want) / np.maximum(np.abs(want), 1e-3)
            assert err.max() < 1e-2
            assert np.abs(got - want).max() < 1e-9          # in fact equal to round-off


def test_16_insertion_phase():
    cos, eps, d = _angles([0, 40, 75]), 6.31 - 0.2826j, 0.006
    a = slab_coefficients(cos, eps, d, F77)
    b = slab_coefficients(cos, eps, d, F77, transmission_phase="insertion")
    shift = np.exp(1j * 2 * np.pi * d * cos / LAM77)
    np.testing.assert_allclose(b.t_s, a.t_s * shift, rtol=1e-12)
    np.testing.assert_allclose(b.t_p, a.t_p * shift, rtol=1e-12)
    np.testing.assert_array_equal(a.r_s, b.r_s)
    # vacuum slab: the insertion transmission is exactly 1
    v = slab_coefficients(cos, 1.0 + 0j, d, F77, transmission_phase="insertion")
    np.testing.assert_allclose(v.t_s, 1, atol=1e-12)
    np.testing.assert_allclose(v.t_p, 1, atol=1e-12)


# --------------------------------------------------------------------------
# Dr.Jit backend
# --------------------------------------------------------------------------
def _grid():
    cos = _angles([0, 15, 35, 55, 70, 85, 89])
    d = np.array([0.0, 5e-4, 2e-3, 6e-3, 0.0125])
    eps = np.array([1.48 - 0.0j, 4.0 + 0j, 2.73 - 0.2j, 5.24 - 0.3225j, 6.31 - 0.2826j,
                    1.0 - 2.3e6j, 12.0 - 3.0j])
    C, D, E = np.meshgrid(cos, d, eps, indexing="ij")
    return (C.ravel().astype(np.float32).astype(np.float64),
            D.ravel().astype(np.float32).astype(np.float64),
            (E.real.astype(np.float32) + 1j * E.imag.astype(np.float32)).ravel())


def test_17_drjit_matches_numpy(drm):
    """Float32 Dr.Jit vs complex128 NumPy on float32-representable inputs:
    |error| < 1e-5 * max(|ref|, 1) (coefficients are O(1); near-zero values
    such as r_p at Brewster are compared absolutely)."""
    mi, dr = drm
    c, d, e = _grid()
    c_dr, d_dr = mi.Float(c.astype(np.float32)), mi.Float(d.astype(np.float32))
    e_dr = mi.Complex2f(mi.Float(e.real.astype(np.float32)), mi.Float(e.imag.astype(np.float32)))
    for phase in ("p2040", "insertion"):
        ref = slab_coefficients(c, e, d, F77, transmission_phase=phase)
        got = slab_coefficients(c_dr, e_dr, d_dr, F77, transmission_phase=phase)
        for g, w in zip(got, ref):
            g = _to_np(dr, g)
            assert (np.abs(g - w) / np.maximum(np.abs(w), 1.0)).max() < 1e-5
    ref = fresnel_coefficients(c, e)
    got = fresnel_coefficients(c_dr, e_dr)
    for g, w in zip(got, ref):
        assert (np.abs(_to_np(dr, g) - w) / np.maximum(np.abs(w), 1.0)).max() < 1e-5
    a_np = energy_gate(c, e, d, F77, f_s=0.3, f_p=0.7)
    a_dr = _to_np(dr, energy_gate(c_dr, e_dr, d_dr, F77, f_s=0.3, f_p=0.7))
    assert np.abs(a_dr - a_np).max() < 1e-5
    # a 0.2 m concrete wall: |q| ~ 740 rad, float32 phase error ~ 5e-5 rad
    ref = slab_coefficients(c, 5.24 - 0.3225j, 0.2, F77)
    got = slab_coefficients(c_dr, mi.Complex2f(5.24, -0.3225), 0.2, F77)
    assert np.abs(_to_np(dr, got.r_s) - ref.r_s).max() < 1e-4


def test_18_drjit_gradients_match_finite_differences(drm):
    """d|R|^2 / d(eps', eps'', d, cos) and dA/d(...) by Dr.Jit reverse-mode AD vs
    central differences of the float64 NumPy version (< 2 % relative)."""
    mi, dr = drm
    pts = np.array([  # eps', eps'', d [m], cos
        [6.31, 0.2826, 0.006, 0.9],
        [5.24, 0.3225, 0.004, 0.6],
        [2.73, 0.05, 0.0125, 0.75],
        [4.0, 0.0, 0.003, 0.95],
        [1.48, 0.03, 0.015, 0.4],
        [12.0, 3.0, 0.001, 0.8],
    ])
    # make the NumPy reference use the exact float32 inputs Dr.Jit sees
    pts = pts.astype(np.float32).astype(np.float64)

    def np_targets(p):
        er, ei, d, c = p
        sc = slab_coefficients(c, er - 1j * ei, d, F77)
        return np.array([abs(sc.r_s) ** 2, abs(sc.r_p) ** 2,
                         0.4 * abs(sc.r_s) ** 2 + 0.6 * abs(sc.r_p) ** 2])

    steps = np.array([1e-6, 1e-7, 1e-9, 1e-7])
    for k_target in range(3):
        ins = [mi.Float(pts[:, j].astype(np.float32)) for j in range(4)]
        for x in ins:
            dr.enable_grad(x)
        er, ei, d, c = ins
        eps = complex_permittivity(er, ei)
        sc = slab_coefficients(c, eps, d, F77)
        if k_target == 0:
            y = dr.squared_norm(sc.r_s)
        elif k_target == 1:
            y = dr.squared_norm(sc.r_p)
        else:
            y = energy_gate(c, eps, d, F77, f_s=0.4, f_p=0.6)
        dr.backward(dr.sum(y))
        grads = np.stack([np.array(dr.grad(x), dtype=np.float64) for x in ins], axis=1)
        for i, p in enumerate(pts):
            for j in range(4):
                hp, hm = p.copy(), p.copy()
                hp[j] += steps[j]
                hm[j] -= steps[j]
                fd = (np_targets(hp)[k_target] - np_targets(hm)[k_target]) / (2 * steps[j])
                g = grads[i, j]
                assert np.isfinite(g)
                assert abs(g - fd) <= 0.02 * abs(fd) + 1e-4 * max(1.0, abs(fd)), \
                    (k_target, i, j, g, fd)


def test_19_drjit_lossless_gradient_finite(drm):
    """eps'' = 0 (lossless) and exact grazing / zero thickness stay NaN-free."""
    mi, dr = drm
    er, ei = mi.Float([4.0, 4.0, 6.31]), mi.Float([0.0, 0.0, 0.0])
    d, c = mi.Float([0.003, 0.0, 0.0]), mi.Float([0.8, 0.0, 1.0])
    for x in (er, ei, d, c):
        dr.enable_grad(x)
    y = energy_gate(c, complex_permittivity(er, ei), d, F77)
    dr.backward(dr.sum(y))
    for x in (er, ei, d, c):
        assert np.all(np.isfinite(np.array(dr.grad(x))))
    assert np.all(np.isfinite(np.array(y)))
    # dA / d eps'' at eps'' = 0 (central difference across eps'' = 0) is nonzero
    fd = (energy_gate(0.8, 4 - 1e-7j, 0.003, F77) - energy_gate(0.8, 4 + 1e-7j, 0.003, F77)) / 2e-7
    assert abs(fd) > 1e-3
    assert float(np.array(dr.grad(ei))[0]) == pytest.approx(fd, rel=0.02)


def test_20_energy_gate_in_unit_interval(drm):
    mi, dr = drm
    cos = _angles(np.linspace(0, 90, 31))[:, None, None]
    d = np.array([0, 1e-4, 1e-3, 6e-3, 0.0125, 0.03, 0.2, 1.0])[None, :, None]
    eps = np.array([itu_material(n, F77).eps_r for n in available_materials(F77)]
                   + [1.0 + 0j, 4.0 + 0j, 80 - 40j, 2 - 1e-8j])[None, None, :]
    for fs, fp in ((0.5, 0.5), (1.0, 0.0), (0.0, 1.0), (0.2, 0.8)):
        a = energy_gate(cos, eps, d, F77, f_s=fs, f_p=fp)
        assert np.all(np.isfinite(a)) and a.min() >= 0 and a.max() <= 1 + 1e-12
        C, D, E = np.broadcast_arrays(cos, d, eps)
        a_dr = _to_np(dr, energy_gate(mi.Float(C.ravel()), mi.Complex2f(
            mi.Float(E.real.ravel()), mi.Float(E.imag.ravel())), mi.Float(D.ravel()), F77,
            f_s=fs, f_p=fp))
        assert np.all(np.isfinite(a_dr)) and a_dr.min() >= 0 and a_dr.max() <= 1 + 1e-5
    # metal at normal incidence reflects essentially everything
    assert energy_gate(1.0, itu_material("metal", F77).eps_r, 0.01, F77) > 0.99
