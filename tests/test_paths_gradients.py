"""AD versus central finite differences for every learnable quantity.

The solver's discrete decisions (hit triangles, barycentrics, random choices)
are frozen with ``samples=`` so that the finite differences and the AD
gradient differentiate the *same* Monte Carlo estimator (attached sampling);
every other quantity -- positions, normals, materials, pose, beam pattern --
is re-evaluated.  Quantities: total path power, a fixed random projection of
the raw ADC, and the min-max range-azimuth loss (paper eq. 7).  Relative
error bound: 2 %.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from helpers import square_plate

import sionna_mmir  # noqa: F401
from sionna_mmir.utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from sionna_mmir.processing.drjit_ra import ra_loss_from_adc  # noqa: E402
from sionna_mmir.radar import RadarConfig  # noqa: E402
from sionna_mmir.radio_devices import CosinePowerPattern  # noqa: E402
from sionna_mmir.scene import load_scene  # noqa: E402
from sionna_mmir.paths import RadarPathSolver  # noqa: E402

RTOL = 0.02
MAT = np.array([4.0, 0.05, 3e-4, 5e-3, 0.5, 8e-3], dtype=np.float32)


def _radar():
    return dataclasses.replace(RadarConfig.awr1843(), num_samples=64)


_plate = square_plate


def _scene(meshes, mats=None):
    sc = load_scene(meshes, radar=_radar())
    for name, obj in sc.mesh_objects.items():
        mat = MAT if mats is None else mats[name]
        obj.vertex_materials = mi.TensorXf(np.tile(mat, (obj.vertex_positions.shape[0], 1)))
    sc.sync()
    return sc


class Harness:
    """Frozen-sample evaluation of a scalar objective of the rendered frame."""

    def __init__(self, scene, objective="power", **opts):
        self.scene, self.objective = scene, objective
        self.opts = dict(num_rays=6000, max_depth=1, seed=5, tx_pattern="cos", rx_pattern="cos")
        self.opts.update(opts)
        self.solver = RadarPathSolver()
        first = self.solver(scene, **self.opts)
        self.samples = first.samples
        radar = scene.radar
        rng = np.random.default_rng(0)
        self.w = rng.standard_normal((2,) + tuple(radar.adc_shape)).astype(np.float32)
        if objective == "ra":
            # target: the scene with a different first-object permittivity and
            # roughness, rendered from other samples (a genuine fit target)
            from sionna_mmir.paths.render import to_numpy
            from sionna_mmir.processing.imaging import range_azimuth
            obj = next(iter(scene.mesh_objects.values()))
            keep = obj.vertex_materials
            mat = np.array(keep)
            mat[:, 0] *= 1.8
            mat[:, 2] *= 0.5
            obj.vertex_materials = mi.TensorXf(mat)
            other = self.solver(scene, **dict(self.opts, seed=self.opts["seed"] + 1))
            obj.vertex_materials = keep
            self.target = range_azimuth(to_numpy(other.adc(radar)), radar)[0]

    def __call__(self):
        p = self.solver(self.scene, samples=list(self.samples), **self.opts)
        if self.objective == "power":
            return p.power()
        adc = p.adc(self.scene.radar)
        if self.objective == "adc":
            return dr.sum(adc.real.array * mi.Float(self.w[0].ravel())
                          + adc.imag.array * mi.Float(self.w[1].ravel()))
        return ra_loss_from_adc(adc, self.scene.radar, self.target)


def _set(owner, key, value):
    setattr(owner, key, value)


def check(h: Harness, owner, key, index, step, sync=True):
    """Return ``(ad, fd)`` for ``owner.<key>[index]`` (a TensorXf / mi.Float attribute)."""
    base_t = getattr(owner, key)
    base = np.array(base_t, dtype=np.float64)
    shape = base.shape

    def make(arr):
        arr = arr.astype(np.float32)
        return mi.TensorXf(arr) if isinstance(base_t, mi.TensorXf) else mi.Float(arr.ravel())

    t = make(base)
    dr.enable_grad(t)
    _set(owner, key, t)
    y = h()
    dr.backward(y)
    ad = float(np.asarray(dr.grad(t)).reshape(shape)[index])
    vals = []
    for s in (1, -1):
        b = base.copy()
        b[index] += s * step
        _set(owner, key, make(b))
        if sync:
            h.scene.sync()
        vals.append(float(np.asarray(h())[0]))
    _set(owner, key, make(base))
    if sync:
        h.scene.sync()
    return ad, (vals[0] - vals[1]) / (2 * step)


def check_fit(h: Harness, owner, key, index, step, n=17):
    """``(ad, fd, se)`` as :func:`check`, ``fd`` the slope at 0 of a cubic
    fitted to ``n`` evaluations over ``[-step, step]`` and ``se`` its
    standard error from the fit's residuals (the float32 noise of the
    objective)."""
    ad, _ = check(h, owner, key, index, step / 4)
    base_t = getattr(owner, key)
    base = np.array(base_t, dtype=np.float64)
    steps = np.linspace(-step, step, n)
    vals = []
    for s in steps:
        b = base.copy()
        b[index] += s
        _set(owner, key, mi.TensorXf(b.astype(np.float32)))
        h.scene.sync()
        vals.append(float(np.asarray(h())[0]))
    _set(owner, key, base_t)
    h.scene.sync()
    coef, cov = np.polyfit(steps, vals, 3, cov=True)
    return ad, float(coef[-2]), float(np.sqrt(cov[-2, -2]))


def _assert_close(ad, fd, what, se=0.0):
    """``|AD - FD| <= max(RTOL |FD|, 3 se)`` (``se``: the FD's standard error
    where it is fitted, :func:`check_fit`)."""
    assert np.isfinite(ad) and np.isfinite(fd) and fd != 0, (what, ad, fd)
    tol = max(RTOL * abs(fd), 3.0 * se)
    assert abs(ad - fd) <= tol, f"{what}: AD {ad:.6e} vs FD {fd:.6e} (+- {se:.1e})"
    assert tol <= 0.1 * abs(fd), f"{what}: FD too noisy to test ({se:.1e} of {fd:.6e})"


def _centre_vertex(obj, near):
    return int(np.argmin(np.linalg.norm(np.asarray(obj.vertex_positions) - near, axis=1)))


@pytest.fixture(scope="module")
def rough_scene():
    return _scene({"wall": _plate([1.6, 0.0, 0.0], 0.8, yaw_deg=8.0, subdiv=3)})


# ------------------------------------------------------------------ materials
@pytest.mark.parametrize("k, step, coherent", [
    (0, 0.02, True), (1, 0.005, True), (2, 1e-5, True),
    (3, 3e-4, False), (4, 0.02, False), (5, 1e-5, True)])
def test_01_material_parameters_on_path_power(rough_scene, k, step, coherent):
    h = Harness(rough_scene, "power", coherent=coherent)
    obj = rough_scene.mesh_objects["wall"]
    v = _centre_vertex(obj, [1.6, 0.05, 0.05])
    ad, fd = check(h, obj, "vertex_materials", (v, k), step)
    _assert_close(ad, fd, f"material {k}")


@pytest.mark.parametrize("k, step", [(0, 0.02), (2, 1e-5)])
def test_02_material_parameters_on_adc(rough_scene, k, step):
    h = Harness(rough_scene, "adc")
    obj = rough_scene.mesh_objects["wall"]
    v = _centre_vertex(obj, [1.6, 0.05, 0.05])
    ad, fd = check(h, obj, "vertex_materials", (v, k), step)
    _assert_close(ad, fd, f"material {k} (ADC)")


@pytest.fixture(scope="module")
def two_plates():
    """Two coarse plates at different range and azimuth (RA-loss tests)."""
    return _scene({"near": _plate([1.4, 0.3, 0.0], 0.4, yaw_deg=-6.0),
                   "far": _plate([2.2, -0.4, 0.0], 0.5, yaw_deg=5.0)})


@pytest.mark.parametrize("k, step", [(0, 0.003), (1, 0.003), (2, 5e-6), (3, 3e-4), (4, 0.02), (5, 3e-6)])
def test_03_material_parameters_on_ra_loss(two_plates, k, step):
    h = Harness(two_plates, "ra")
    obj = two_plates.mesh_objects["near"]
    ad, fd = check(h, obj, "vertex_materials", (1, k), step)
    _assert_close(ad, fd, f"material {k} (RA loss)")


# -------------------------------------------------------------------- normals
@pytest.mark.parametrize("objective", ["power", "adc"])
def test_04_vertex_normal(rough_scene, objective):
    h = Harness(rough_scene, objective, coherent=False)
    obj = rough_scene.mesh_objects["wall"]
    v = _centre_vertex(obj, [1.6, 0.05, 0.05])
    ad, fd = check(h, obj, "vertex_normals", (v, 1), 0.01)
    _assert_close(ad, fd, f"normal ({objective})")


# ---------------------------------------------------------- vertex positions
@pytest.mark.parametrize("coherent, scattering", [(True, False), (False, True)],
                         ids=["specular", "diffuse"])
def test_05_vertex_position_on_path_power(coherent, scattering):
    """A plate corner moved in-plane changes the plate area: power ~ A^2 (PO) or A (diffuse)."""
    sc = _scene({"plate": _plate([1.5, 0.0, 0.0], 0.3, yaw_deg=0.0 if coherent else 10.0)})
    h = Harness(sc, "power", coherent=coherent, scattering=scattering, cone_angle_deg=12.0)
    obj = sc.mesh_objects["plate"]
    ad, fd = check(h, obj, "vertex_positions", (2, 1), 2e-3)
    _assert_close(ad, fd, "vertex position (power)")


def test_06a_vertex_position_on_ra_loss(two_plates):
    h = Harness(two_plates, "ra")
    ad, fd = check(h, two_plates.mesh_objects["near"], "vertex_positions", (1, 1), 5e-5)
    _assert_close(ad, fd, "vertex position (RA loss)")


def test_06_vertex_position_on_adc():
    sc = _scene({"plate": _plate([1.5, 0.0, 0.0], 0.3, yaw_deg=4.0, subdiv=1)})
    obj = sc.mesh_objects["plate"]
    for objective in ("adc",):
        h = Harness(sc, objective, cone_angle_deg=12.0)
        ad, fd = check(h, obj, "vertex_positions", (2, 0), 2e-5)
        _assert_close(ad, fd, f"vertex position ({objective})")


# ---------------------------------------------------------------------- pose
@pytest.mark.parametrize("objective", ["power", "adc", "ra"])
def test_07_pose_translation_and_rotation(rough_scene, two_plates, objective):
    scene = two_plates if objective == "ra" else rough_scene
    h = Harness(scene, objective)
    steps = {"power": (1e-2, 1e-2), "adc": (2e-5, 1e-3), "ra": (2e-5, 2e-3)}[objective]
    ad, fd = check(h, scene, "position", 1, steps[0], sync=False)
    _assert_close(ad, fd, f"pose y ({objective})")
    ad, fd = check(h, scene, "orientation", 0, steps[1], sync=False)
    _assert_close(ad, fd, f"pose yaw ({objective})")


# -------------------------------------------------------------- beam pattern
@pytest.mark.parametrize("objective", ["power", "adc", "ra"])
def test_08_beam_pattern_parameter(rough_scene, two_plates, objective):
    scene = two_plates if objective == "ra" else rough_scene
    pattern = CosinePowerPattern(q_az=2.0, q_el=8.0, n_elements=scene.radar.num_tx)
    h = Harness(scene, objective, tx_pattern=pattern)
    ad, fd = check(h, pattern, "log_q_az", 0, 0.05, sync=False)
    _assert_close(ad, fd, f"beam log q_az ({objective})")


# --------------------------------------------------------------- multi-bounce
def test_09_multibounce_gradients():
    """Depth 3 with a floor: materials and a floor vertex through 2-3 bounce paths."""
    floor = trimesh.Trimesh(np.array([[0.5, -1, -0.4], [3, -1, -0.4], [3, 1, -0.4], [0.5, 1, -0.4]]),
                            [[0, 2, 1], [0, 3, 2]], process=False).subdivide().subdivide()
    metal = np.array([1.0, 1e6, 1e-5, 1e-2, 0.9, 0.01], np.float32)
    sc = _scene({"wall": _plate([1.6, 0.0, 0.0], 0.8, yaw_deg=8.0, subdiv=2), "floor": floor},
                mats={"wall": MAT, "floor": metal})
    h = Harness(sc, "power", max_depth=3, num_rays=8000)
    wall = sc.mesh_objects["wall"]
    v = _centre_vertex(wall, [1.6, 0.0, -0.3])
    ad, fd = check(h, wall, "vertex_materials", (v, 2), 1e-5)
    _assert_close(ad, fd, "sigma_h (depth 3)")
    floor_obj = sc.mesh_objects["floor"]
    fv = _centre_vertex(floor_obj, [1.75, 0.0, -0.4])
    # 0.1 mm: with frozen samples the FD converges (-34 % at 1 mm, -3.6 % at 0.3 mm)
    ad, fd = check(h, floor_obj, "vertex_positions", (fv, 2), 1e-4)
    _assert_close(ad, fd, "floor vertex z (depth 3)")


def test_10_facet_quadrature_gradients(rough_scene):
    """sampling='facets' (deterministic quadrature): material, normal and vertex position."""
    obj = rough_scene.mesh_objects["wall"]
    v = _centre_vertex(obj, [1.6, 0.05, 0.05])
    h = Harness(rough_scene, "adc", sampling="facets", cone_angle_deg=30.0)
    for key, k, step in (("vertex_materials", 0, 0.02), ("vertex_normals", 1, 0.01),
                         ("vertex_positions", 0, 2e-5)):
        ad, fd = check(h, obj, key, (v, k), step)
        _assert_close(ad, fd, f"{key}[{k}] (facets)")


def test_11_facet_image_chain_gradients():
    """Facet quadrature at depth 2: a coherent chain integrates over its last
    surface with its Rx leg from the receiver's image in the earlier mirrors
    (floor -> wall chains: the floor's), so the floor's normals and vertex
    heights move the ADC phase through the unfolded chain (AD vs finite
    differences).  The normal's derivative is weak against the float32 noise
    of the ADC sum (its two-point differences scatter by ~10 %, and by the
    CPU's vector width), so its finite difference is the slope of a cubic
    fitted over 17 steps, compared within three of its standard errors."""
    floor = trimesh.Trimesh(np.array([[0.5, -1, -0.4], [3, -1, -0.4], [3, 1, -0.4], [0.5, 1, -0.4]]),
                            [[0, 2, 1], [0, 3, 2]], process=False).subdivide().subdivide()
    metal = np.array([1.0, 1e6, 1e-5, 1e-2, 0.9, 0.01], np.float32)
    sc = _scene({"wall": _plate([1.6, 0.0, 0.0], 0.8, yaw_deg=8.0, subdiv=2), "floor": floor},
                mats={"wall": MAT, "floor": metal})
    h = Harness(sc, "adc", max_depth=2, sampling="facets", cone_angle_deg=40.0, scattering=False)
    p = h.solver(sc, samples=list(h.samples), **h.opts)
    assert np.any(p.depth == 2)                              # chains exist
    floor_obj = sc.mesh_objects["floor"]
    fv = _centre_vertex(floor_obj, [1.75, 0.0, -0.4])
    ad, fd, se = check_fit(h, floor_obj, "vertex_normals", (fv, 1), 0.08)
    _assert_close(ad, fd, "floor vertex_normals[1] (facets, depth 2)", se)
    ad, fd = check(h, floor_obj, "vertex_positions", (fv, 2), 2e-5)
    _assert_close(ad, fd, "floor vertex_positions[2] (facets, depth 2)")
    wall = sc.mesh_objects["wall"]
    v = _centre_vertex(wall, [1.6, 0.0, -0.3])
    ad, fd = check(h, wall, "vertex_materials", (v, 0), 0.02)
    _assert_close(ad, fd, "wall eps' (facets, depth 2)")


def test_12_gradients_through_solver_pruning(rough_scene):
    """``min_rel_power`` drops weak paths inside the solver (a gather in the AD
    graph): material and normal gradients of the kept paths' ADC still match
    central finite differences (the kept set does not change within the steps)."""
    obj = rough_scene.mesh_objects["wall"]
    v = _centre_vertex(obj, [1.6, 0.05, 0.05])
    h = Harness(rough_scene, "adc", sampling="facets", cone_angle_deg=30.0, min_rel_power=1e-3)
    full = RadarPathSolver()(rough_scene, **dict(h.opts, min_rel_power=0.0))
    kept = h.solver(rough_scene, samples=list(h.samples), **h.opts)
    assert 0 < kept.shape[2] < full.shape[2]
    for key, k, step in (("vertex_materials", 0, 0.02), ("vertex_normals", 1, 0.01)):
        ad, fd = check(h, obj, key, (v, k), step)
        _assert_close(ad, fd, f"{key}[{k}] (pruned)")
