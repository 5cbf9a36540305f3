"""RadarPathSolver against closed forms: RCS, MIMO coherence, reciprocity, Doppler, bad input.

References (independent of the code):

* flat plate, normal incidence, far field: ``sigma = 4 pi A^2 / lambda^2``
  (physical optics; Knott, Shaeffer & Tuley, *Radar Cross Section*, Table 6.1)
* triangular trihedral of edge ``a`` on its symmetry axis:
  ``sigma = 4 pi a^4 / (3 lambda^2)`` (same table)
* radar equation ``|a|^2 = G_t G_r lambda^2 sigma / ((4 pi)^3 R^4)``
* point-target azimuth as seen from the aperture phase centre
* monostatic delay rate of a target receding at ``v``: ``2 v / c``
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

import sionna_mmir  # noqa: F401
from sionna_mmir.errors import ConfigError, InputValueError
from sionna_mmir.radar import RadarConfig
from sionna_mmir.scene import load_scene

from helpers import aperture_centre, square_plate

from sionna_mmir.paths import RadarPathSolver, render, to_numpy  # noqa: E402
from sionna_mmir.processing.imaging import range_azimuth  # noqa: E402

C = 299_792_458.0
F0 = 77e9
LAM = C / F0


def _square(centre, size, subdiv=3):
    """Square plate facing the radar (-x), ``subdiv`` 4:1 splits."""
    return square_plate(centre, size, subdiv=subdiv)


def _coherent_sum(paths, f=F0):
    a, tau, _ = paths.numpy()
    return (a * np.exp(2j * np.pi * f * tau)).sum(axis=2)


def _rcs_dbsm(value, R, gain=1.0):
    return 10 * np.log10(np.abs(value) ** 2 * (4 * np.pi) ** 3 * R ** 4 / (LAM ** 2 * gain ** 2))


def test_01_pec_plate_rcs_matches_physical_optics():
    a, R = 0.1, 20.0          # far field: 2 D^2 / lambda = 10 m < R
    scene = load_scene({"plate": _square([R, 0, 0], a)}, materials={"plate": "metal"},
                       radar=RadarConfig.dense(1, 1))
    paths = RadarPathSolver()(scene, num_rays=100_000, max_depth=1, cone_angle_deg=0.5,
                              tx_pattern="iso", rx_pattern="iso", seed=1)
    got = _rcs_dbsm(_coherent_sum(paths)[0, 0], R)
    expected = 10 * np.log10(4 * np.pi * a ** 4 / LAM ** 2)
    assert abs(got - expected) < 1.0, (got, expected)


def test_02_trihedral_peak_rcs():
    a, R = 0.15, 30.0
    axis = np.ones(3) / np.sqrt(3)
    radar = RadarConfig.dense(1, 1, position=tuple(R * axis),
                              orientation=(np.radians(-135.0), np.arcsin(1 / np.sqrt(3)), 0.0))
    V = np.array([[0, 0, 0], [a, 0, 0], [0, a, 0], [0, 0, a]], float)
    # one mesh, faces not sharing vertices across the creases (flat shading normals)
    faces = [trimesh.Trimesh(V, [f], process=False).subdivide().subdivide()
             for f in ([0, 1, 2], [0, 2, 3], [0, 3, 1])]
    scene = load_scene({"trihedral": trimesh.util.concatenate(faces)},
                       materials={"trihedral": "metal"}, radar=radar)
    paths = RadarPathSolver()(scene, num_rays=100_000, max_depth=3, cone_angle_deg=0.25,
                              tx_pattern="iso", rx_pattern="iso", seed=2)
    got = _rcs_dbsm(_coherent_sum(paths)[0, 0], R)
    expected = 10 * np.log10(4 * np.pi * a ** 4 / (3 * LAM ** 2))
    assert abs(got - expected) < 2.0, (got, expected)
    # the triple bounce carries it: single-bounce alone is far below
    K = paths.info["hits"]
    a_np, tau, _ = paths.numpy()
    one = (a_np[0, 0, :K] * np.exp(2j * np.pi * F0 * tau[0, 0, :K])).sum()
    assert _rcs_dbsm(one, R) < expected - 15


def test_03_monostatic_plate_power_follows_radar_equation_with_patterns():
    """cos^q element gains enter as G_t G_r at the target direction."""
    from sionna_mmir.radio_devices import CosinePowerPattern

    a, R, az = 0.1, 20.0, np.radians(10.0)
    centre = R * np.array([np.cos(az), np.sin(az), 0.0])
    plate = _square([0, 0, 0], a)
    plate.apply_transform(trimesh.transformations.rotation_matrix(az, [0, 0, 1]))
    plate.apply_translation(centre)
    scene = load_scene({"plate": plate}, materials={"plate": "metal"}, radar=RadarConfig.dense(1, 1))
    pat = CosinePowerPattern(q_az=2.0, q_el=10.0)
    paths = RadarPathSolver()(scene, num_rays=100_000, max_depth=1, cone_angle_deg=11.0,
                              tx_pattern=pat, rx_pattern=pat, seed=3)
    g = float(pat.gain_np(np.array([np.cos(az), np.sin(az), 0.0])))
    got = _rcs_dbsm(_coherent_sum(paths)[0, 0], R, gain=g)
    assert abs(got - 10 * np.log10(4 * np.pi * a ** 4 / LAM ** 2)) < 1.0


def test_04_reciprocity_swapping_tx_and_rx_arrays_transposes_the_channel():
    base = RadarConfig.awr1843()
    swapped = dataclasses.replace(base, tx_positions=base.rx_positions[:3].copy(),
                                  rx_positions=np.vstack([base.tx_positions, [[0, 0.01, 0]]]),
                                  tdm_order=(0, 1, 2))
    orig = dataclasses.replace(base, tx_positions=swapped.rx_positions.copy(),
                               rx_positions=swapped.tx_positions.copy(), tdm_order=(0, 1, 2, 3))
    wall = _square([2.5, 0.2, 0.0], 1.0)
    wall.apply_transform(trimesh.transformations.rotation_matrix(0.2, [0, 0, 1], point=[2.5, 0.2, 0]))
    h = []
    for radar in (orig, swapped):
        scene = load_scene({"wall": wall}, radar=radar)
        p = RadarPathSolver()(scene, num_rays=5000, max_depth=2, seed=4)
        h.append(_coherent_sum(p))
    np.testing.assert_allclose(h[0], h[1].T, rtol=2e-3, atol=1e-3 * np.abs(h[0]).max())


@pytest.fixture(scope="module")
def cascade_target():
    radar = RadarConfig.mmwcas(num_chirps=1)
    az_true, R = np.radians(20.0), 4.0
    centre = R * np.array([np.cos(az_true), np.sin(az_true), 0.0])
    plate = _square([0, 0, 0], 0.06, subdiv=2)
    plate.apply_transform(trimesh.transformations.rotation_matrix(az_true, [0, 0, 1]))
    plate.apply_translation(centre)
    scene = load_scene({"target": plate}, materials={"target": "metal"}, radar=radar)
    return scene, radar, centre


def test_05_mimo_coherence_small_scatterer_at_true_azimuth(cascade_target):
    scene, radar, centre = cascade_target
    adc = to_numpy(render(scene, num_rays=150_000, max_depth=1, cone_angle_deg=24.0, seed=5))
    ra, ranges, az = range_azimuth(adc, radar)
    r_i, a_i = np.unravel_index(np.argmax(ra), ra.shape)
    rel = centre - aperture_centre(radar)
    az_expected = np.degrees(np.arctan2(rel[1], rel[0]))
    assert abs(np.degrees(az[a_i]) - az_expected) < 0.5, (np.degrees(az[a_i]), az_expected)
    assert abs(ranges[r_i] - np.linalg.norm(rel)) < 2 * radar.range_resolution


def test_06_same_seed_gives_bit_identical_adc(cascade_target):
    scene, radar, _ = cascade_target
    opts = dict(num_rays=20_000, max_depth=2, cone_angle_deg=24.0, seed=11)
    a = to_numpy(render(scene, **opts))
    b = to_numpy(render(scene, **opts))
    c = to_numpy(render(scene, **dict(opts, seed=12)))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_07_moving_target_delay_rate_and_doppler():
    v = 1.5                       # m/s receding along +x
    R = 3.0
    radar = RadarConfig.awr1843(num_chirps=32)
    scene = load_scene({"plate": _square([R, 0, 0], 0.2)}, materials={"plate": "metal"}, radar=radar)
    paths = RadarPathSolver()(scene, num_rays=20_000, max_depth=1, cone_angle_deg=3.0,
                              velocities={"plate": (v, 0.0, 0.0)}, seed=6)
    _, _, rate = paths.numpy()
    w = np.abs(paths.numpy()[0])
    mean_rate = float((rate * w).sum() / w.sum())
    assert abs(mean_rate - 2 * v / C) < 0.01 * 2 * v / C
    from sionna_mmir.processing.imaging import range_doppler

    rd, ranges, vels = range_doppler(to_numpy(paths.adc(radar)), radar)[:3]
    _, d_i = np.unravel_index(np.argmax(rd), rd.shape)
    assert abs(abs(vels[d_i]) - v) <= radar.max_velocity / radar.num_chirps * 1.01


# ------------------------------------------------------------------ bad input
def test_08_radar_inside_closed_geometry_raises():
    box = trimesh.creation.box((2.0, 2.0, 2.0))
    scene = load_scene({"box": box}, radar=RadarConfig.dense(1, 1))
    with pytest.raises(InputValueError, match="inside closed geometry"):
        RadarPathSolver()(scene, num_rays=100)


def test_09_out_of_band_material_raises_unless_allowed():
    plate = _square([2, 0, 0], 0.5, subdiv=0)
    with pytest.raises(ConfigError, match="marble"):
        load_scene({"p": plate}, materials={"p": "marble"})
    load_scene({"p": plate}, materials={"p": "marble"}, allow_out_of_band=True)


def test_10_nan_and_unphysical_scene_tensors_raise():
    import mitsuba as mi

    scene = load_scene({"p": _square([2, 0, 0], 0.5, subdiv=0)}, radar=RadarConfig.dense(1, 1))
    obj = scene.mesh_objects["p"]
    good = np.array(obj.vertex_materials)
    bad = good.copy()
    bad[1, 2] = -1e-3
    obj.vertex_materials = mi.TensorXf(bad.astype(np.float32))
    with pytest.raises(InputValueError, match="sigma_h < 0"):
        RadarPathSolver()(scene, num_rays=100)
    bad = good.copy()
    bad[0, 0] = np.nan
    obj.vertex_materials = mi.TensorXf(bad.astype(np.float32))
    with pytest.raises(InputValueError, match="NaN"):
        RadarPathSolver()(scene, num_rays=100)
    obj.vertex_materials = mi.TensorXf(good.astype(np.float32))
    pos = np.array(obj.vertex_positions)
    pos[2, 1] = np.inf
    obj.vertex_positions = mi.TensorXf(pos.astype(np.float32))
    with pytest.raises(InputValueError, match="vertex_positions"):
        RadarPathSolver()(scene, num_rays=100)


def test_11_bad_solver_options_raise():
    scene = load_scene({"p": _square([2, 0, 0], 0.5, subdiv=0)}, radar=RadarConfig.dense(1, 1))
    for kw in ({"num_rays": 0}, {"max_depth": 0}, {"seed": -1}, {"cone_angle_deg": 120},
               {"velocities": {"nope": (1, 0, 0)}}, {"min_rel_power": -1e-3},
               {"min_rel_power": 1.0}, {"min_rel_power": float("nan")},
               {"min_rel_power": True}, {"min_rel_power": "1e-5"}):
        with pytest.raises(ConfigError):
            RadarPathSolver()(scene, **kw)
    with pytest.raises(ConfigError, match="no radar"):
        RadarPathSolver()(load_scene({"p": _square([2, 0, 0], 0.5, subdiv=0)}))


def test_12_empty_degenerate_and_nan_meshes_raise(tmp_path):
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    with pytest.raises(InputValueError, match="empty"):
        load_scene({"e": empty})
    degenerate = trimesh.Trimesh(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]), [[0, 1, 2]],
                                 process=False)
    with pytest.raises(InputValueError, match="degenerate"):
        load_scene({"d": degenerate})
    nan = trimesh.Trimesh(np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0.0]]), [[0, 1, 2]],
                          process=False)
    with pytest.raises(InputValueError, match="NaN"):
        load_scene({"n": nan})


def test_13_no_hits_gives_empty_paths_and_zero_adc():
    radar = RadarConfig.dense(1, 1)
    scene = load_scene({"behind": _square([-3, 0, 0], 0.5, subdiv=0)}, radar=radar)
    paths = RadarPathSolver()(scene, num_rays=1000)
    assert paths.num_paths == 0
    assert not np.any(to_numpy(paths.adc(radar)))


def test_14_free_space_diffraction_redirects_a_small_power_fraction(monkeypatch):
    """Rays hitting near a plate's edges are diffracted (FSD) and continue past it."""
    import drjit as dr

    from sionna_mmir.paths.transport import continuation

    counts = []
    orig = continuation.diffract

    def spy(*a, **k):
        mask, wo = orig(*a, **k)
        counts.append(int(dr.count(mask)[0]))
        return mask, wo

    monkeypatch.setattr(continuation, "diffract", spy)
    scene = load_scene({"plate": _square([2, 0, 0], 0.4), "wall": _square([4, 0, 0], 3.0)},
                       materials={"plate": "metal", "wall": "concrete"},
                       radar=RadarConfig.awr1843())
    s = RadarPathSolver()
    p0 = float(s(scene, num_rays=20_000, max_depth=3, seed=1).power()[0])
    p1 = float(s(scene, num_rays=20_000, max_depth=3, seed=1, diffraction=True).power()[0])
    assert counts and counts[0] > 0
    assert p1 != p0 and abs(p1 - p0) < 0.05 * p0


def test_14b_diffraction_sees_the_rim_of_a_flat_shaded_plate_only(monkeypatch):
    """A plate whose faces share no vertex (flat shading) diffracts at its rim,
    as the same plate with shared vertices does, not at every triangle seam."""
    import drjit as dr

    from sionna_mmir.paths.geometry import SceneGeometry
    from sionna_mmir.paths.transport import continuation, diffraction

    shared = _square([2, 0, 0], 0.4, subdiv=2)
    split = trimesh.Trimesh(shared.vertices[shared.faces.reshape(-1)],
                            np.arange(shared.faces.size).reshape(-1, 3), process=False)
    counts = {}
    orig = continuation.diffract

    def spy(*a, **k):
        mask, wo = orig(*a, **k)
        counts.setdefault(key, []).append(int(dr.count(mask)[0]))
        return mask, wo

    monkeypatch.setattr(continuation, "diffract", spy)
    n_edges = {}
    for key, plate in (("shared", shared), ("split", split)):
        scene = load_scene({"plate": plate, "wall": _square([4, 0, 0], 3.0, subdiv=0)},
                           materials={"plate": "metal", "wall": "concrete"},
                           radar=RadarConfig.awr1843())
        n_edges[key] = len(diffraction.fsd_setup(SceneGeometry(scene), LAM, None)["edges"])
        RadarPathSolver()(scene, num_rays=20_000, max_depth=2, seed=1, diffraction=True)
    assert n_edges["split"] == n_edges["shared"] == 4 * 4 + 4      # plate rim (4 x 4) + wall
    assert counts["split"] == counts["shared"] and counts["shared"][0] > 0


def test_15_facet_quadrature_plate_rcs_and_low_variance():
    """sampling='facets': one ray per facet centroid, exact per-facet physical optics."""
    a, R = 0.1, 20.0
    plate = _square([R, 0, 0], a, subdiv=5)
    scene = load_scene({"plate": plate}, materials={"plate": "metal"},
                       radar=RadarConfig.dense(1, 1))
    s = RadarPathSolver()
    p = s(scene, max_depth=1, cone_angle_deg=1.0, tx_pattern="iso", rx_pattern="iso",
          sampling="facets")
    assert p.num_paths == len(plate.faces)
    got = _rcs_dbsm(_coherent_sum(p)[0, 0], R)
    assert abs(got - 10 * np.log10(4 * np.pi * a ** 4 / LAM ** 2)) < 0.5
    # the coherent part does not depend on the seed at all
    p, q = (s(scene, max_depth=1, cone_angle_deg=1.0, tx_pattern="iso", rx_pattern="iso",
              sampling="facets", scattering=False, seed=k) for k in (0, 9))
    np.testing.assert_allclose(_coherent_sum(q), _coherent_sum(p), rtol=1e-5)
    with pytest.raises(ConfigError, match="sampling"):
        s(scene, sampling="sobol")


def _po_plate_reference(R, a, h=0.0005):
    """Scalar monostatic physical optics of a broadside square PEC plate of side ``a``
    at range ``R`` by brute-force summation on an ``h`` grid, relative to the infinite
    plane (image theory, stationary phase ``pi / (k R)``): independent of the solver."""
    k = 2 * np.pi / LAM
    xs = np.arange(-a / 2 + h / 2, a / 2, h)
    tot = 0j
    for x0 in np.array_split(xs, 20):
        X, Y = np.meshgrid(x0, xs, indexing="ij")
        r = np.sqrt(R * R + X * X + Y * Y)
        tot += np.sum((R / r) / r ** 2 * np.exp(-2j * k * r)) * h * h
    return abs(tot) / (np.pi / (k * R))


@pytest.mark.parametrize("subdiv", [1, 4])
def test_16_facet_quadrature_converges_in_the_near_field_of_a_large_plate(subdiv):
    """A 0.6 m plate at 1.5 m is ~60 Fresnel zones wide: facets are split into
    sub-facets until the phase is linear across each, so the coherent return matches
    brute-force physical optics whatever the tessellation (one point per facet of
    15 cm would be off by orders of magnitude)."""
    R, a = 1.5, 0.6
    plate = _square([R, 0, 0], a, subdiv=subdiv)
    scene = load_scene({"plate": plate}, materials={"plate": "metal"},
                       radar=RadarConfig.dense(1, 1))
    p = RadarPathSolver()(scene, max_depth=1, tx_pattern="iso", rx_pattern="iso",
                          sampling="facets", scattering=False)
    assert p.num_paths > 4 * len(plate.faces)              # facets were split
    got = np.abs(_coherent_sum(p)[0, 0]) / (LAM / (4 * np.pi * 2 * R))
    ref = _po_plate_reference(R, a)
    assert abs(20 * np.log10(got / ref)) < 0.5, (got, ref)
    with pytest.raises(ConfigError, match="facet_fresnel"):
        RadarPathSolver()(scene, sampling="facets", facet_fresnel=0.0)


def _dihedral_reference(O, u1, u2, w, a, h=0.0005):
    """Double-bounce physical optics of a PEC dihedral by image theory, brute force:
    the first plate's surface integral towards the radar's image in the second
    plate, kept where the image ray crosses the second plate (both orders)."""
    k = 2 * np.pi / LAM
    c = np.zeros(3)
    n1 = np.cross(u1, w); n1 /= np.linalg.norm(n1)
    n2 = np.cross(w, u2); n2 /= np.linalg.norm(n2)
    n = int(round(a / h))
    t = (np.arange(n) + 0.5) / n
    U, V = np.meshgrid(t, t, indexing="ij")
    total = 0j
    for uA, nA, uB, nB in ((u1, n1, u2, n2), (u2, n2, u1, n1)):
        y = O + U.ravel()[:, None] * uA + V.ravel()[:, None] * w
        T = c - 2 * np.dot(c - O, nB) * nB
        d = T - y
        L2 = np.linalg.norm(d, axis=1)
        dh = d / L2[:, None]
        s = np.dot(O - y, nB) / (dh @ nB)
        zb = y + s[:, None] * dh - O
        su, sw = zb @ uB / a ** 2, zb @ w / a ** 2
        ok = (s > 0) & (s < L2) & (su >= 0) & (su <= 1) & (sw >= 0) & (sw <= 1)
        L1 = np.linalg.norm(y - c, axis=1)
        cos_in = np.abs(((y - c) / L1[:, None]) @ nA)
        cos_o = np.abs(dh @ nA)
        val = 0.5 * (cos_in + cos_o) * np.exp(-1j * k * (L1 + L2)) / (L1 * L2) * (a / n) ** 2
        total += np.sum(val[ok]) / (4 * np.pi)
    return abs(total)


@pytest.mark.parametrize("subdiv", [2, 4])
def test_17_dihedral_double_bounce_matches_image_theory_physical_optics(subdiv):
    """A 90 deg PEC dihedral (0.3 m plates) at 2 m, in its near field: the coherent
    double bounce (the exit aperture on the second plate, Rx leg from the receiver's image)
    matches a brute-force image-theory PO integral, whatever the tessellation."""
    R, a = 2.0, 0.3
    s2 = np.sqrt(0.5)
    O = np.array([R, 0.0, -a / 2])
    u1, u2, w = np.array([-s2, s2, 0]) * a, np.array([-s2, -s2, 0]) * a, np.array([0, 0, a])

    def plate(corners):
        m = trimesh.Trimesh(np.array(corners, float), [[0, 1, 2], [0, 2, 3]], process=False)
        for _ in range(subdiv):
            m = m.subdivide()
        return m

    meshes = {"a": plate([O, O + u1, O + u1 + w, O + w]), "b": plate([O, O + w, O + u2 + w, O + u2])}
    scene = load_scene(meshes, materials={"a": "metal", "b": "metal"}, radar=RadarConfig.dense(1, 1))
    p = RadarPathSolver()(scene, max_depth=2, tx_pattern="iso", rx_pattern="iso",
                          sampling="facets", scattering=False)
    amp, tau, _ = p.numpy()
    sel = p.depth == 2
    got = abs((amp[..., sel] * np.exp(2j * np.pi * F0 * tau[..., sel])).sum(axis=2)[0, 0])
    ref = _dihedral_reference(O, u1, u2, w, a)
    assert abs(20 * np.log10(got / ref)) < 0.5, (got, ref)


def test_18_facet_quadrature_independent_of_mixed_facet_sizes():
    """Facets of different sizes are split into different numbers of sub-facets; the
    weights must follow each sub-facet (a plate meshed coarse on one half and fine on
    the other returns what brute-force PO gives for the whole plate)."""
    R, a = 1.5, 0.6
    coarse = _square([R, 0, 0], a, subdiv=1)
    fine = _square([R, 0, 0], a, subdiv=4)
    # left half from the coarse mesh, right half from the fine one (y < 0 / y >= 0)
    def half(m, keep):
        c = m.triangles_center[:, 1]
        sel = keep(c)
        return trimesh.Trimesh(m.vertices, m.faces[sel], process=False)
    mixed = trimesh.util.concatenate([half(coarse, lambda y: y < 0), half(fine, lambda y: y >= 0)])
    scene = load_scene({"plate": mixed}, materials={"plate": "metal"},
                       radar=RadarConfig.dense(1, 1))
    p = RadarPathSolver()(scene, max_depth=1, tx_pattern="iso", rx_pattern="iso",
                          sampling="facets", scattering=False)
    got = np.abs(_coherent_sum(p)[0, 0]) / (LAM / (4 * np.pi * 2 * R))
    ref = _po_plate_reference(R, a)
    assert abs(20 * np.log10(got / ref)) < 0.5, (got, ref)


@pytest.mark.parametrize("sampling", ["facets", "random"])
def test_19_solver_pruning_keeps_exactly_the_paths_above_the_threshold(sampling):
    """``min_rel_power``: the pruned paths are the subset of the unpruned ones
    whose power at the first Tx-Rx pair, ``|c|^2 g_t[0]^2 g_r[0]^2``, exceeds
    the threshold x the strongest's (computed here from the unpruned paths'
    factors), in the same order, with the same factors (1e-6); 0 keeps all."""
    plates = {"near": _square([1.5, 0.3, 0.0], 0.3, subdiv=2),
              "far": _square([4.0, -0.8, 0.2], 0.6, subdiv=3)}
    radar = dataclasses.replace(RadarConfig.mmwcas(num_chirps=2), num_samples=64)
    scene = load_scene(plates, materials={"near": "metal", "far": "concrete"}, radar=radar)
    opts = dict(max_depth=2, sampling=sampling, num_rays=4000, seed=3)
    full = RadarPathSolver()(scene, **opts)
    same = RadarPathSolver()(scene, min_rel_power=0.0, **opts)
    c, g_t, tau_t, g_r, tau_r, _ = full.factors.numpy()
    np.testing.assert_array_equal(same.factors.numpy()[0], c)
    power = np.abs(c) ** 2 * g_t[0] ** 2 * g_r[0] ** 2
    # a threshold between two neighbouring powers about the median (0.1 % apart
    # at least, clear of float32 rounding)
    r = np.sort(power / power.max())
    i = next(i for i in range(r.size // 2, r.size) if r[i] > 1.001 * r[i - 1])
    th = float(np.sqrt(r[i] * r[i - 1]))
    keep = np.flatnonzero(power > th * power.max())
    assert 0 < keep.size < c.size
    pruned = RadarPathSolver()(scene, min_rel_power=th, **opts)
    got = pruned.factors.numpy()
    assert got[0].shape == (keep.size,)
    for mine, ref in zip(got[:5], (c, g_t, tau_t, g_r, tau_r)):
        np.testing.assert_allclose(mine, ref[..., keep], rtol=1e-6, atol=0)
    np.testing.assert_array_equal(pruned.depth, full.depth[keep])
