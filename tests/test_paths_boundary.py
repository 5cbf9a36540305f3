"""Geometry and pose gradients against finite differences with re-traced rays.

Unlike ``test_paths_gradients.py`` (frozen samples), every finite-difference
evaluation here traces its rays anew, so samples cross silhouettes and the
visibility changes: the derivative the renderer must match is that of the
*expected* image.  With the boundary term (``SolverOptions.boundary``,
:mod:`sionna_mmir.paths.boundary`) the AD gradient must agree within 10 %
and in sign; without it the occluder case is far off.

Scene: a metal wall behind the beam's full cone (so no wall edge is in the
cone) and a metal plate turned 40 deg in front of it, in the beam of a
narrow ``cos^60`` element pattern (whose two-way gain at the cone's rim is
-50 dB: the cone's rim adds no boundary term).  The objective is the energy
of the raw ADC, ``sum |s|^2``.  Estimates are averaged over a few seeds of
jittered-grid (stratified) rays, each finite difference and AD gradient with
the same seeds (common random numbers).

``BOUNDARY_REPORT=1 python -m pytest tests/test_paths_boundary.py -s`` also
prints the AD gradient without the boundary term for every case (the figures
of ``docs/results.md``).
"""
from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from helpers import square_plate

import sionna_mmir  # noqa: F401
from sionna_mmir.utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from sionna_mmir.paths import RadarPathSolver  # noqa: E402
from sionna_mmir.radar import RadarConfig  # noqa: E402
from sionna_mmir.radio_devices import CosinePowerPattern  # noqa: E402
from sionna_mmir.scene import load_scene  # noqa: E402

METAL = np.array([1.0, 1e6, 1e-5, 1e-2, 0.9, 0.01], np.float32)
RTOL = 0.10
SEEDS = (0, 1, 2)


def _scene():
    radar = dataclasses.replace(RadarConfig.awr1843(), num_samples=16, num_chirps=1)
    wall = square_plate([1.5, 0.0, 0.0], 1.4, subdiv=7)
    occ = square_plate([1.0, 0.1, 0.0], 0.2, yaw_deg=40.0, subdiv=4)
    sc = load_scene({"wall": wall, "occ": occ}, radar=radar)
    for obj in sc.mesh_objects.values():
        obj.vertex_materials = mi.TensorXf(np.tile(METAL, (obj.vertex_positions.shape[0], 1)))
    sc.sync()
    return sc


@pytest.fixture(scope="module")
def scene():
    return _scene()


def _options(**kw):
    pat = CosinePowerPattern(q_az=60.0, q_el=60.0)
    return dict(num_rays=300_000, max_depth=1, scattering=False, cone_angle_deg=22.0,
                stratified=True, tx_pattern=pat, rx_pattern=pat, boundary_samples=2048, **kw)


def _energy(scene, seed, **kw):
    paths = RadarPathSolver()(scene, seed=seed, **_options(**kw))
    adc = paths.adc(scene.radar)
    return dr.sum(dr.square(adc.real.array) + dr.square(adc.imag.array))


class Param:
    """One scalar parameter of the scene: a direction in a scene tensor."""

    def __init__(self, scene, owner, key, direction, **opts):
        self.scene, self.owner, self.key, self.opts = scene, owner, key, opts
        self.base = np.array(getattr(owner, key), dtype=np.float64)
        self.dir = np.broadcast_to(np.asarray(direction, dtype=np.float64), self.base.shape)

    def set(self, step=0.0, grad=False):
        a = (self.base + step * self.dir).astype(np.float32)
        t = mi.TensorXf(mi.Float(a.ravel()), a.shape)
        if grad:
            dr.enable_grad(t)
        setattr(self.owner, self.key, t)
        if self.key == "vertex_positions":
            self.scene.sync()
        return t

    def fd(self, step, seed):
        vals = []
        for s in (step, -step):
            self.set(s)
            vals.append(float(np.asarray(_energy(self.scene, seed, **self.opts))[0]))
        self.set(0.0)
        return (vals[0] - vals[1]) / (2 * step)

    def ad(self, seed, boundary):
        t = self.set(0.0, grad=True)
        dr.backward(_energy(self.scene, seed, boundary=boundary, **self.opts))
        g = float(np.sum(np.asarray(dr.grad(t)).reshape(self.base.shape) * self.dir))
        self.set(0.0)
        return g


def compare(param, step, seeds=SEEDS, without=False):
    """``(fd, ad with the boundary term[, ad without])`` averaged over ``seeds``."""
    fd = np.mean([param.fd(step, s) for s in seeds])
    ad = np.mean([param.ad(s, True) for s in seeds])
    report = os.environ.get("BOUNDARY_REPORT") == "1"
    off = np.mean([param.ad(s, False) for s in seeds]) if (without or report) else None
    if report:
        print(f"\n[report] FD {fd:.4e}  AD with boundary {ad:.4e}  without {off:.4e}")
    return (fd, ad, off) if without else (fd, ad)


def _check(fd, ad, what):
    assert np.isfinite(ad) and np.isfinite(fd) and fd != 0, (what, ad, fd)
    assert np.sign(ad) == np.sign(fd) and abs(ad - fd) <= RTOL * abs(fd), \
        f"{what}: AD {ad:.4e} vs re-traced FD {fd:.4e}"


def _occluder_y(scene):
    obj = scene.mesh_objects["occ"]
    return Param(scene, obj, "vertex_positions", [0.0, 1.0, 0.0])


def test_01_occluder_sliding_across_a_wall(scene):
    fd, ad, ad_off = compare(_occluder_y(scene), 2e-3, without=True)
    print(f"occluder y: FD {fd:.4e}  AD+boundary {ad:.4e}  AD interior only {ad_off:.4e}")
    _check(fd, ad, "occluder y")
    # without the boundary term the gradient misses the occlusion: far off
    assert abs(ad_off - fd) > 0.5 * abs(fd), (fd, ad_off)


def test_02_plate_edge_moving_across_the_beam(scene):
    obj = scene.mesh_objects["occ"]
    V = np.array(obj.vertex_positions, dtype=np.float64)
    # the plate's edge nearest the boresight: its vertices move sideways
    # (the plate stretches), the rest stays
    edge = np.isclose(V[:, 1], V[:, 1].min(), atol=1e-6)
    d = np.zeros_like(V)
    d[edge, 1] = 1.0
    fd, ad = compare(Param(scene, obj, "vertex_positions", d), 2e-3)
    print(f"plate edge y: FD {fd:.4e}  AD+boundary {ad:.4e}")
    _check(fd, ad, "plate edge y")


def test_03_radar_translation(scene):
    fd, ad = compare(Param(scene, scene, "position", [0.0, 1.0, 0.0]), 2e-3)
    print(f"radar y: FD {fd:.4e}  AD+boundary {ad:.4e}")
    _check(fd, ad, "radar y")


def test_04_radar_yaw(scene):
    # turned 3 deg off the wall's normal: at 0 the energy is at its maximum
    # (zero derivative).  A turn moves every ray over the wall's triangles,
    # so random rays re-sample the whole image; the facet quadrature
    # (deterministic, nodes fixed on the mesh) keeps the difference smooth
    keep = scene.orientation
    scene.orientation = mi.TensorXf(mi.Float(np.radians([3.0, 0.0, 0.0]).astype(np.float32)), (3,))
    try:
        fd, ad = compare(Param(scene, scene, "orientation", [1.0, 0.0, 0.0], sampling="facets"),
                         np.radians(0.5), seeds=(0,))
    finally:
        scene.orientation = keep
    print(f"radar yaw: FD {fd:.4e}  AD+boundary {ad:.4e}")
    _check(fd, ad, "radar yaw")


def test_05_boundary_paths_change_no_rendered_value(scene):
    on = RadarPathSolver()(scene, seed=0, **_options(boundary=True))
    off = RadarPathSolver()(scene, seed=0, **_options(boundary=False))
    assert on.num_paths > off.num_paths
    a_on = on.adc(scene.radar)
    a_off = off.adc(scene.radar)
    np.testing.assert_allclose(np.asarray(a_on.real.array), np.asarray(a_off.real.array),
                               rtol=1e-6, atol=1e-12)


def test_06_silhouettes_of_a_cube_and_options_checked():
    import trimesh

    from sionna_mmir.errors import ConfigError
    from sionna_mmir.paths import SolverOptions
    from sionna_mmir.paths.boundary import SilhouetteEdges

    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    V, F = np.asarray(box.vertices, float), np.asarray(box.faces, np.int64)
    edges = SilhouetteEdges(F, V)
    assert len(edges.v0) == 12                 # the cube's edges; face diagonals are flat
    # seen from a generic point, the outline of a cube is a hexagon: six edges
    assert edges.silhouettes(V, np.array([3.0, 2.0, 1.5])).size == 6
    # face-on, the outline is the near face's four edges (the far face's four
    # fold edges line up with them)
    s = edges.sample(V, np.array([3.0, 0.0, 0.0]), 400, 0)
    assert len(s) == 400 and np.all(s.inv_density > 0)
    near = np.isclose(s.point[:, 0], 0.5)
    # a sample on the near face's edges points away from the cube
    out = np.einsum("ij,ij->i", s.far[near], s.point[near] - np.array([0.5, 0.0, 0.0]))
    assert np.all(out > 0)
    for bad in (dict(boundary_samples=0), dict(boundary="yes"), dict(stratified=2.5)):
        with pytest.raises(ConfigError):
            SolverOptions(**bad)
