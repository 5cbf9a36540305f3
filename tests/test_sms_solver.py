"""Specular manifold sampling inside the radar path solver (``SolverOptions.sms``).

Targets (PEC, one isotropic monostatic element, 77 GHz, depth 1): a
smooth-shaded icosphere and the side wall of a 256-sided cylinder at 3 m.
Their RCS is checked against the near-range geometric-optics closed form of
a curved mirror (``comparisons/sms_curved.md`` holds the brute-force
physical-optics comparison), their gradient against finite differences of
re-traced solver calls, and the Bernoulli-trial weights against their
expectation.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sionna_mmir

sionna_mmir.init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from sionna_mmir.errors import ConfigError  # noqa: E402
from sionna_mmir.paths import RadarPathSolver, SolverOptions  # noqa: E402
from sionna_mmir.paths.transport.specular import trial_weights  # noqa: E402
from sionna_mmir.radar import RadarConfig  # noqa: E402
from sionna_mmir.scene import load_scene  # noqa: E402
from helpers import assert_same_paths  # noqa: E402

F0 = 77e9
LAM = 299_792_458.0 / F0
R = 3.0


def _radar():
    radar = RadarConfig.dense(1, 1)
    return radar, np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)


def _sphere(a, centre, subdivisions=4):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=a)
    m.apply_translation(centre)
    return m


def _cylinder(a, L, centre, sides=256):
    th = 2 * np.pi * np.arange(sides) / sides + np.pi
    ring = np.c_[a * np.cos(th), a * np.sin(th)]
    v = np.concatenate([np.c_[ring, np.full(sides, -L / 2)], np.c_[ring, np.full(sides, L / 2)]])
    i = np.arange(sides)
    j = (i + 1) % sides
    f = np.concatenate([np.c_[i, j, j + sides], np.c_[i, j + sides, i + sides]])
    m = trimesh.Trimesh(v + centre, f, process=False)
    m.fix_normals()
    return m


def _rcs(scene, radar, cone, n=20_000, **kw):
    p = RadarPathSolver()(scene, max_depth=1, num_rays=n, seed=1, cone_angle_deg=cone,
                          scattering=False, tx_pattern="iso", rx_pattern="iso", **kw)
    amp, tau, _ = p.numpy()
    coef = (amp * np.exp(2j * np.pi * F0 * tau)).sum()
    return 10 * np.log10(np.abs(coef) ** 2 * (4 * np.pi) ** 3 * R ** 4 / LAM ** 2)


def test_sphere_and_cylinder_within_1db_of_geometric_optics():
    radar, c = _radar()
    a = 0.3
    sph = load_scene({"t": _sphere(a, c + [R + a, 0, 0])}, materials={"t": "metal"}, radar=radar)
    cone = float(np.degrees(np.arctan(1.2 * a / R)))
    go = 10 * np.log10(np.pi * R ** 2 * a ** 2 / (R + a) ** 2)
    assert abs(_rcs(sph, radar, cone, sms=True) - go) < 1.0
    a, L = 0.2, 0.6
    cyl = load_scene({"t": _cylinder(a, L, c + [R + a, 0, 0])}, materials={"t": "metal"},
                     radar=radar)
    cone = float(np.degrees(np.arctan(0.6 * L / R)))
    go = 10 * np.log10(np.pi * R ** 2 * a / (R + a))
    assert abs(_rcs(cyl, radar, cone, sms=True) - go) < 1.0


def test_default_output_unchanged_by_the_option():
    radar, c = _radar()
    scene = load_scene({"t": _sphere(0.3, c + [R + 0.3, 0, 0], 3)}, materials={"t": "metal"},
                       radar=radar)
    cone = float(np.degrees(np.arctan(0.36 / R)))
    a = RadarPathSolver()(scene, num_rays=2000, seed=2, cone_angle_deg=cone).numpy()[0]
    b = RadarPathSolver()(scene, num_rays=2000, seed=2, cone_angle_deg=cone,
                          sms=False).numpy()[0]
    np.testing.assert_array_equal(a, b)


def test_gradient_of_the_radius_matches_retraced_fd():
    """d(power)/d(scale) of a sphere scaled about its centre: AD (IFT through
    the walk, the curvature term) vs central FD of two re-traced calls and
    the closed form ``P ~ a^2 / (R^2 (R + a)^2)`` (``R + a`` fixed).  The
    re-traced power of the faceted sphere moves by a few per cent from one
    scale to the next (two-point differences scatter by ~+-40 % at 1-5 %
    steps), so the FD is the slope of a cubic through eleven calls over
    +-20 %, compared within 10 % or three of its standard errors.  The
    facet quadrature seeds the walks (deterministic weights ``1 / c``: the
    Bernoulli draws of random seeds would add their own noise to a
    difference of two calls)."""
    radar, c = _radar()
    a = 0.3
    centre = c + np.array([R + a, 0, 0])
    base = _sphere(a, np.zeros(3))
    cone = float(np.degrees(np.arctan(1.4 * a / R)))
    kw = dict(max_depth=1, sampling="facets", seed=1, cone_angle_deg=cone, scattering=False,
              tx_pattern="iso", rx_pattern="iso", sms=True)

    def power(scale, grad=False):
        m = base.copy()
        m.apply_scale(scale)
        m.apply_translation(centre)
        scene = load_scene({"t": m}, materials={"t": "metal"}, radar=radar)
        if not grad:
            return float(RadarPathSolver()(scene, **kw).power()[0])
        obj = scene.mesh_objects["t"]
        s = mi.Float(1.0)
        dr.enable_grad(s)
        v = np.asarray(obj.vertex_positions, dtype=np.float32)
        cen = mi.Point3f(*(float(x) for x in centre))
        V = mi.Point3f(*(mi.Float(v[:, i]) for i in range(3)))
        V = cen + (V - cen) * s
        obj.vertex_positions = mi.TensorXf(dr.ravel(V), (v.shape[0], 3))
        y = RadarPathSolver()(scene, **kw).power()
        dr.backward(y)
        return float(dr.grad(s)[0])

    ad = power(1.0, grad=True)
    p0 = power(1.0)
    steps = np.linspace(-0.2, 0.2, 11)
    coef, cov = np.polyfit(steps, [power(1.0 + h) for h in steps], 3, cov=True)
    fd, se = coef[-2], np.sqrt(cov[-2, -2])
    closed = p0 * (2.0 + 2.0 * a / R)            # d ln P / ds = 2 / s + 2 a / R
    assert np.sign(ad) == np.sign(fd)
    assert abs(ad - fd) < max(0.1 * abs(fd), 3 * se), (ad, fd, se)
    assert 3 * se < 0.2 * abs(fd), (fd, se)      # the re-traced slope is informative
    assert abs(ad - closed) < 0.05 * abs(closed)


def test_trial_weights_estimate_inverse_probability():
    rng = np.random.default_rng(0)
    pos = np.r_[np.zeros((30, 3)), np.ones((10, 3))]
    obj = np.zeros(40, np.int64)
    valid = np.ones(40, bool)
    det = trial_weights(pos, obj, valid, 100, rng, deterministic=True)
    np.testing.assert_allclose(det, np.r_[np.full(30, 100 / 30), np.full(10, 10.0)])
    draws = np.mean([trial_weights(pos, obj, valid, 100, rng, False) for _ in range(400)], 0)
    np.testing.assert_allclose([draws[:30].mean(), draws[30:].mean()], [100 / 30, 10.0],
                               rtol=0.06)
    # every specular point counted once: sum over its seeds of W / N -> 1
    assert abs(det[:30].sum() / 100 - 1) < 1e-12


def test_options_validate_the_switches():
    assert SolverOptions.fit(sms=True, fsd_coherent=True).sms
    with pytest.raises(ConfigError):
        SolverOptions(sms="yes")
    with pytest.raises(ConfigError):
        SolverOptions(diffraction=True, fsd_coherent=True)


def _bistatic_sphere_go(a, centre, src, dst):
    """Geometric-optics amplitude ratio of a sphere's reflection from ``src``
    to ``dst`` (unit spherical source): ``(1 / s1) sqrt(rho1 rho2 /
    ((rho1 + s2)(rho2 + s2)))``, ``1/rho1 = 1/s1 + 2/(a cos)``, ``1/rho2 =
    1/s1 + 2 cos / a`` (principal sections of the reflected wavefront)."""
    from scipy.optimize import minimize

    def pt(ang):
        th, ph = ang
        return centre + a * np.array([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph),
                                      np.sin(th)])

    r = minimize(lambda g: np.linalg.norm(pt(g) - src) + np.linalg.norm(pt(g) - dst),
                 [0.0, np.pi], method="Nelder-Mead", options=dict(xatol=1e-10, fatol=1e-13))
    x = pt(r.x)
    s1, s2 = np.linalg.norm(x - src), np.linalg.norm(x - dst)
    cos = np.dot((x - centre) / a, (src - x) / s1)
    r1, r2 = 1 / (1 / s1 + 2 / (a * cos)), 1 / (1 / s1 + 2 * cos / a)
    return (1 / s1) * np.sqrt(r1 * r2 / ((r1 + s2) * (r2 + s2)))


def test_floor_bounce_chain_within_1db_of_geometric_optics():
    """Depth 2, a sphere 0.6 m above a metal floor: the two orders of the
    floor-sphere chain against twice the image-source closed form (the
    radar's image in the floor lights the sphere); the mirror chains alone
    are off by more."""
    radar, c = _radar()
    a, hf = 0.3, 0.6
    centre = c + np.array([R + a, 0, 0])
    fz = c[2] - hf
    floor = trimesh.Trimesh(np.array([[c[0] + 0.5, -2, fz], [c[0] + 6, -2, fz],
                                      [c[0] + 6, 2, fz], [c[0] + 0.5, 2, fz]]),
                            [[0, 1, 2], [0, 2, 3]], process=False)
    scene = load_scene({"sphere": _sphere(a, centre, 5), "floor": floor},
                       materials={"sphere": "metal", "floor": "metal"}, radar=radar)
    image = c.copy()
    image[2] = 2 * fz - c[2]
    ref = 2 * LAM / (4 * np.pi) * _bistatic_sphere_go(a, centre, image, c)
    out = {}
    for sms in (False, True):
        p = RadarPathSolver()(scene, max_depth=2, num_rays=20_000, seed=1, cone_angle_deg=20,
                              scattering=False, tx_pattern="iso", rx_pattern="iso", sms=sms)
        amp, tau, _ = p.numpy()
        coef = (amp[0, 0] * np.exp(2j * np.pi * F0 * tau[0, 0]))[p.depth == 2].sum()
        out[sms] = 20 * np.log10(abs(coef) / ref)
    assert abs(out[True]) < 1.0
    assert abs(out[False]) > 1.0


def test_replay_reproduces_the_sms_paths():
    """Frozen samples (``samples=``) replay the walks, trial counts and masks."""
    radar, c = _radar()
    scene = load_scene({"t": _sphere(0.3, c + [R + 0.3, 0, 0], 4)}, materials={"t": "metal"},
                       radar=radar)
    kw = dict(max_depth=2, num_rays=20_000, seed=1, sms=True)
    p = RadarPathSolver()(scene, **kw)
    q = RadarPathSolver()(scene, samples=p.samples, **kw)
    assert_same_paths(p, q)
