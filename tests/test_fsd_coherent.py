"""Coherent free-space diffraction (``SolverOptions.fsd_coherent``).

Knife edge: a metal half-plane screen (3 m x 1.5 m, its top edge the knife
edge) halfway between a unit source and a receiver 2 m apart; the
diffracted field relative to the unobstructed one is compared with the
Fresnel-Kirchhoff closed form ``F(nu) = (1 + j) / 2 int_nu^inf exp(-j pi
t^2 / 2) dt`` (``scipy.special.fresnel``) over shadow depths ``nu`` = 0.5 ..
3, and its gradient with respect to the edge height with central finite
differences of re-evaluated fields (edges found again, nodes placed again,
visibility traced again).  The solver test checks that blocked connections
gain diffracted paths with finite gradients and that the default output
does not change.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.special import fresnel

import sionna_mmir

sionna_mmir.init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from sionna_mmir.paths import RadarPathSolver  # noqa: E402
from sionna_mmir.paths.geometry import SceneGeometry, Tape  # noqa: E402
from sionna_mmir.paths.transport.fsd_coherent import (boundary_edges, edge_field,  # noqa: E402
                                                      fresnel_tail)
from sionna_mmir.radar import RadarConfig  # noqa: E402
from sionna_mmir.scene import load_scene  # noqa: E402
from helpers import assert_same_paths  # noqa: E402

LAM = 299_792_458.0 / 77e9
D1 = D2 = 1.0
NU_PER_M = np.sqrt(2 * (D1 + D2) / (LAM * D1 * D2))


def _screen(top, W=1.5, H=1.5):
    v = np.array([[0, -W, -H], [0, W, -H], [0, W, top], [0, -W, top]], float)
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def _closed(nu):
    s, c = fresnel(nu)
    return (1 + 1j) / 2 * ((0.5 - c) - 1j * (0.5 - s))


def _field(scene, grad_tensor=None):
    geo = SceneGeometry(scene)
    S, P = mi.Point3f(-D1, 0.0, 0.0), mi.Point3f(D2, 0.0, 0.0)
    return edge_field(geo, boundary_edges(geo), S, P, LAM, Tape())[:2]


def test_fresnel_tail_matches_scipy():
    w = np.linspace(-4, 4, 161)
    re, im = fresnel_tail(mi.Float(w.astype(np.float32)))
    s, c = fresnel(np.abs(w))
    ref = (0.5 - c) - 1j * (0.5 - s)
    ref = np.where(w < 0, (1 - 1j) - ref, ref)
    assert np.max(np.abs(np.asarray(re) + 1j * np.asarray(im) - ref)) < 3e-3


@pytest.mark.parametrize("nu", [0.5, 1.0, 2.0, 3.0])
def test_knife_edge_shadow_within_1db_of_fresnel(nu):
    D_re, D_im = _field(load_scene({"s": _screen(nu / NU_PER_M)}))
    D = float(D_re[0]) + 1j * float(D_im[0])
    F = _closed(nu)
    assert abs(20 * np.log10(abs(D) / abs(F))) < 1.0
    assert abs(np.angle(D / F)) < 0.1          # the phase is carried too


@pytest.mark.parametrize("nu", [1.0, 2.0])
def test_knife_edge_gradient_matches_retraced_fd(nu):
    top = nu / NU_PER_M
    scene = load_scene({"s": _screen(top)})
    obj = scene.mesh_objects["s"]
    t = mi.TensorXf(np.array(obj.vertex_positions, dtype=np.float32))
    dr.enable_grad(t)
    obj.vertex_positions = t
    D_re, D_im = _field(scene)
    dr.backward(dr.sum(D_re * D_re + D_im * D_im))
    g = np.array(dr.grad(t)).reshape(-1, 3)
    ad = g[2, 2] + g[3, 2]                      # both vertices of the edge move up
    vals = []
    for s in (1, -1):
        a, b = _field(load_scene({"s": _screen(top + s * 1e-3)}))
        vals.append(float(a[0]) ** 2 + float(b[0]) ** 2)
    fd = (vals[0] - vals[1]) / 2e-3
    assert np.sign(ad) == np.sign(fd)
    assert abs(ad - fd) < 0.05 * abs(fd)


def _blocked_scene():
    """A floor-bounce chain to a plate whose direct connection a screen blocks."""
    def rect(p0, u, v):
        p0 = np.asarray(p0, float)
        V = np.array([p0, p0 + u, p0 + np.add(u, v), p0 + v], float)
        return trimesh.Trimesh(V, [[0, 1, 2], [0, 2, 3]], process=False)

    radar = RadarConfig.dense(1, 1)
    c = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
    meshes = {"floor": rect(c + [0.5, -1, -1], [4, 0, 0], [0, 2, 0]),
              "target": rect(c + [3, -0.15, -0.15], [0, 0.3, 0], [0, 0, 0.3]),
              "screen": rect(c + [1.5, -1, -0.2], [0, 2, 0], [0, 0, 0.7])}
    return load_scene(meshes, materials={k: "metal" for k in meshes}, radar=radar)


def test_solver_adds_differentiable_diffracted_paths():
    scene = _blocked_scene()
    kw = dict(max_depth=2, num_rays=20_000, seed=1, scattering=False, tx_pattern="iso",
              rx_pattern="iso")
    off = RadarPathSolver()(scene, **kw)
    off_default = RadarPathSolver()(scene, fsd_coherent=False, **kw)
    np.testing.assert_array_equal(off.numpy()[0], off_default.numpy()[0])
    obj = scene.mesh_objects["screen"]
    t = mi.TensorXf(np.array(obj.vertex_positions, dtype=np.float32))
    dr.enable_grad(t)
    obj.vertex_positions = t
    on = RadarPathSolver()(scene, fsd_coherent=True, **kw)
    assert on.num_paths > off.num_paths
    dr.backward(on.power())
    g = np.array(dr.grad(t))
    assert np.all(np.isfinite(g)) and np.abs(g).max() > 0


def _wall_scene(h, screen=True):
    """A side-wall bounce to a 4 cm plate 3 m away; a screen halfway, its top
    edge ``h`` above the plate's line of sight to the radar."""
    def rect(p0, u, v):
        p0 = np.asarray(p0, float)
        V = np.array([p0, p0 + u, p0 + np.add(u, v), p0 + v], float)
        return trimesh.Trimesh(V, [[0, 1, 2], [0, 2, 3]], process=False)

    radar = RadarConfig.dense(1, 1)
    c = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
    meshes = {"wall": rect(c + [0.3, -1, -1], [0, 0, 2], [4, 0, 0]),
              "target": rect(c + [3, -0.02, -0.02], [0, 0, 0.04], [0, 0.04, 0])}
    if screen:
        meshes["screen"] = rect(c + [1.5, -0.6, -2], [0, 2.6, 0], [0, 0, 2 + h])
    return load_scene(meshes, materials={k: "metal" for k in meshes}, radar=radar), c


WALL_KW = dict(max_depth=2, num_rays=200_000, seed=1, scattering=False, tx_pattern="iso",
               rx_pattern="iso", cone_angle_deg=60)
PER_M = np.sqrt(2 * 3.0 / (LAM * 1.5 * 1.5))


def _target_paths(p, c):
    g = p.geometry.numpy()
    return (p.depth == 2) & (np.abs(g["x_tx"][:, 0] - c[0] - 3) < 1e-3), g["x_tx"]


@pytest.mark.parametrize("nu", [1.0, 2.5])
def test_solver_knife_edge_per_path_within_1db(nu):
    """In the solver: each diffracted path against the same path without the
    screen is ``|F(nu_i)|``, ``nu_i`` from its own point (1 dB)."""
    h = nu / PER_M
    out = []
    for on in (False, True):
        scene, c = _wall_scene(h, screen=on)
        p = RadarPathSolver()(scene, fsd_coherent=on, **WALL_KW)
        sel, x = _target_paths(p, c)
        out.append((np.abs(p.numpy()[0][0, 0][sel]), x[sel]))
    (a_open, x_open), (a_fsd, x_fsd) = out
    assert len(a_open) >= 3 and len(a_fsd) == len(a_open)
    for a, x in zip(a_open, x_open):
        j = np.argmin(np.linalg.norm(x_fsd - x, axis=1))
        nu_i = (h - (x[2] - c[2]) / 2) * PER_M
        assert abs(20 * np.log10(a_fsd[j] / a / abs(_closed(nu_i)))) < 1.0


def test_solver_knife_edge_gradient_matches_retraced_fd():
    """d(power of the diffracted paths)/d(edge height) in the solver: AD
    through the screen's vertices vs central FD of two re-traced calls."""
    h = 1.5 / PER_M

    def power(dh, grad=False):
        scene, c = _wall_scene(h + dh)
        obj = scene.mesh_objects["screen"]
        t = mi.TensorXf(np.array(obj.vertex_positions, dtype=np.float32))
        if grad:
            dr.enable_grad(t)
        obj.vertex_positions = t
        p = RadarPathSolver()(scene, fsd_coherent=True, **{**WALL_KW, "num_rays": 60_000})
        sel, _ = _target_paths(p, c)
        y = dr.sum(dr.select(mi.Bool(sel), dr.square(p.a_re) + dr.square(p.a_im), 0.0))
        if not grad:
            return float(y[0])
        dr.backward(y)
        g = np.array(dr.grad(t)).reshape(-1, 3)
        return float(g[2, 2] + g[3, 2])               # the top edge's two vertices

    ad = power(0.0, grad=True)
    fd = (power(1e-3) - power(-1e-3)) / 2e-3
    assert ad != 0.0 and np.sign(ad) == np.sign(fd)
    assert abs(ad - fd) < 0.05 * abs(fd)


def test_replay_reproduces_the_diffracted_paths():
    scene = _blocked_scene()
    kw = dict(max_depth=2, num_rays=20_000, seed=1, scattering=False, fsd_coherent=True)
    p = RadarPathSolver()(scene, **kw)
    q = RadarPathSolver()(scene, samples=p.samples, **kw)
    assert_same_paths(p, q)
