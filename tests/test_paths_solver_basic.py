"""RadarPathSolver against its reference twin :func:`sionna_mmir.paths.solver_basic.solve_basic`.

The twin writes the solver's coherent estimator out literally (float64 NumPy,
one ray at a time; subset in its module docstring).  Both draw the same
candidate rays, so the comparison is path by path: the same paths in the same
order, the same per-pair delays and amplitudes, and the same ADC (the
solver's through its Dr.Jit factorised synthesiser, the twin's through the
literal :func:`~sionna_mmir.fmcw.synthesize_adc_basic`).

Tolerances, from the solver's float32 arithmetic (the twin is float64):

* delays: points at <= 4 m are rebuilt from float32 barycentrics, a few ulp
  (2.4e-7 m each) per coordinate, so legs agree to ~1e-6 m = 3e-15 s;
  ``DELAY_TOL = 2e-14 s`` (6 um, 0.01 rad of carrier phase at 77 GHz)
  leaves a factor of ~7.
* amplitudes: the triangle average's phase ``q . (P_i - x)`` (``|q| = 2 k``
  = 3200 rad/m) takes the same float32 rounding of the points, ~5e-7 m, i.e.
  ~1.5e-3 rad (a phase error; the magnitudes agree to 1e-6); per path
  ``|a - a_twin| <= AMP_TOL max |a|`` with ``AMP_TOL = 5e-3`` (measured
  <= 1.2e-3 with the triangle average, 1e-6 without).
* ADC: the coherent sum cancels (an oblique plate returns ~1/30 of the sum of
  its path magnitudes), which amplifies the per-path rounding by the same
  factor; ``ADC_TOL_DB = -50`` (relative error energy), measured -57 to -70 dB.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sionna_mmir  # noqa: F401
from sionna_mmir.fmcw import synthesize_adc_basic
from sionna_mmir.radar import RadarConfig
from sionna_mmir.scene import load_scene

from helpers import square_plate

from sionna_mmir.paths import RadarPathSolver, to_numpy  # noqa: E402
from sionna_mmir.paths.solver_basic import solve_basic  # noqa: E402

import mitsuba as mi  # noqa: E402

DELAY_TOL = 2e-14
AMP_TOL = 5e-3
ADC_TOL_DB = -50.0
OPTIONS = dict(num_rays=1000, scattering=False, seed=3)


def _plate(corners, subdiv=4):
    m = trimesh.Trimesh(np.array(corners, float), [[0, 1, 2], [0, 2, 3]], process=False)
    for _ in range(subdiv):
        m = m.subdivide()
    return m


def _dihedral(R=2.0, a=0.3, z=0.0):
    """A 90 deg dihedral of ``a`` x ``a`` plates, crease vertical, opening to the radar
    (2.7 cm triangles: ``k D^2 / R < 1``, the triangle average applies)."""
    s2 = np.sqrt(0.5)
    O = np.array([R, 0.0, z - a / 2])
    u1, u2, w = np.array([-s2, s2, 0]) * a, np.array([-s2, -s2, 0]) * a, np.array([0, 0, a])
    return {"a": _plate([O, O + u1, O + u1 + w, O + w]),
            "b": _plate([O, O + w, O + u2 + w, O + u2])}


def _compare(scene, **options):
    """Figures of the solver against the twin: ``(paths, twin, delay error [s],
    amplitude error / max |a|, ADC error [dB])``."""
    radar = scene.radar
    paths = RadarPathSolver()(scene, **OPTIONS, **options)
    twin = solve_basic(scene, **OPTIONS, **options)
    a, tau, _ = paths.numpy()
    assert a.shape == twin.a.shape and np.array_equal(paths.depth, twin.depth)
    pts = paths.geometry.numpy()["x_tx"]
    assert np.abs(pts - twin.points).max() < 1e-5          # the same paths, same order
    d_tau = float(np.abs(tau - twin.tau).max())
    d_amp = float(np.abs(a - twin.a).max() / np.abs(twin.a).max())
    adc = to_numpy(paths.adc(radar))
    ref = synthesize_adc_basic(radar, twin.a, twin.tau)
    adc_db = float(20 * np.log10(np.linalg.norm(adc - ref) / np.linalg.norm(ref)))
    return paths, twin, d_tau, d_amp, adc_db


def _check(d_tau, d_amp, adc_db):
    assert d_tau < DELAY_TOL, d_tau
    assert d_amp < AMP_TOL, d_amp
    assert adc_db < ADC_TOL_DB, adc_db


@pytest.mark.parametrize("yaw, subdiv", [(0.0, 4), (25.0, 4), (50.0, 4), (25.0, 2)])
def test_01_metal_plate_at_several_angles_depth_1(yaw, subdiv):
    """A 0.3 m PEC plate at 3 m, turned by ``yaw``: single-bounce physical optics
    (specular at 0 deg, side lobes beyond).  Split 4 times (2 cm triangles,
    ``k D^2 / R ~ 0.4``) every hit carries the exact triangle average; split
    twice (``k D^2 / R ~ 6``) none does (the point sample)."""
    scene = load_scene({"plate": square_plate([3, 0, 0], 0.3, yaw_deg=yaw, subdiv=subdiv)},
                       materials={"plate": "metal"}, radar=RadarConfig.awr1843())
    paths, twin, *figures = _compare(scene, max_depth=1, cone_angle_deg=6.0)
    assert paths.num_paths > 100
    _check(*figures)


def test_02_metal_dihedral_double_bounce():
    """A 90 deg PEC dihedral at 2 m: the depth-2 chains (receiver's image, mirror
    continuation, unfolded area density) agree path by path."""
    scene = load_scene(_dihedral(), materials={"a": "metal", "b": "metal"},
                       radar=RadarConfig.awr1843())
    paths, twin, *figures = _compare(scene, max_depth=2, cone_angle_deg=8.0)
    assert (twin.depth == 2).sum() > 100
    _check(*figures)


def test_03_occluder_in_front_of_a_dihedral():
    """A small plate at 1.2 m hides part of the dihedral: primary rays stop on
    it and shadow rays from the dihedral to the array are blocked by it."""
    meshes = dict(_dihedral(), front=square_plate([1.2, 0.03, 0.02], 0.08, subdiv=1))
    scene = load_scene(meshes, materials={"a": "metal", "b": "metal", "front": "metal"},
                       radar=RadarConfig.awr1843())
    paths, twin, *figures = _compare(scene, max_depth=2, cone_angle_deg=8.0)
    objects = paths.geometry.numpy()["objects"]
    names = list(scene.mesh_objects)
    assert (objects == names.index("front")).sum() > 10        # the occluder is seen
    open_ = solve_basic(load_scene(_dihedral(), materials={"a": "metal", "b": "metal"},
                                   radar=RadarConfig.awr1843()),
                        **OPTIONS, max_depth=2, cone_angle_deg=8.0)
    assert (twin.depth == 2).sum() < (open_.depth == 2).sum()  # and it hides chains
    _check(*figures)


def test_04_rough_glass_dihedral():
    """A glass dihedral (ITU-R P.2040 slab, 6 mm thick: complex r_s != -r_p) with
    0.3 mm roughness: slab coefficients, polarisation and both coherent losses
    ``eta`` (continuation) and ``eta_b`` (bistatic) agree."""
    scene = load_scene(_dihedral(), materials={"a": "glass", "b": "glass"},
                       radar=RadarConfig.awr1843())
    for obj in scene.mesh_objects.values():
        m = np.array(obj.vertex_materials)
        m[:, 2] = 0.3e-3
        obj.vertex_materials = mi.TensorXf(m)
    paths, twin, *figures = _compare(scene, max_depth=2, cone_angle_deg=8.0)
    assert (twin.depth == 2).sum() > 100
    _check(*figures)


def test_05_options_outside_the_subset_raise():
    scene = load_scene({"plate": square_plate([3, 0, 0], 0.3)}, materials={"plate": "metal"},
                       radar=RadarConfig.awr1843())
    for bad in ({"scattering": True}, {"max_depth": 3}, {"sampling": "facets"},
                {"diffraction": True}, {"min_rel_power": 1e-3}, {"max_depth": 2, "rr_depth": 1}):
        with pytest.raises(ValueError, match="subset"):
            solve_basic(scene, **{**OPTIONS, **bad})
