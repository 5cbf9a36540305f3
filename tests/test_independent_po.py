"""The independent reference renderer (:mod:`sionna_mmir.independent`) against closed forms.

References (independent of the code under test):

* flat plate, normal incidence, far field: ``sigma = 4 pi A^2 / lambda^2``;
  rotated by ``theta`` about an edge direction:
  ``sigma cos^2(theta) sinc^2(k a sin(theta))`` (physical optics; Knott,
  Shaeffer & Tuley, *Radar Cross Section*, Table 6.1 and Ch. 5)
* 90 deg dihedral of two ``a x b`` plates on its bisector:
  ``8 pi a^2 b^2 / lambda^2``; triangular trihedral of edge ``a`` on its
  symmetry axis: ``4 pi a^4 / (3 lambda^2)`` (same table)
* radar equation in amplitude ``|h| = lambda sqrt(sigma) / ((4 pi)^{3/2} R^2)``
* Fresnel reflection of a half-space ``(1 - n) / (1 + n)`` at normal
  incidence; a lossless half-wave slab is transparent, a quarter-wave slab
  reflects ``2 r / (1 + r^2)``
* Kirchhoff rough-surface sigma0 against its defining Hankel transform
"""
from __future__ import annotations

import ast
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from sionna_mmir.errors import ConfigError, InputValueError
from sionna_mmir.independent import render_reference
from sionna_mmir.radar import RadarConfig

from helpers import square_plate

C = 299_792_458.0
RADAR = RadarConfig.dense(1, 1)
FC = RADAR.center_frequency
LAM = C / FC
K = 2 * np.pi / LAM
ISO = dict(tx_pattern="iso", rx_pattern="iso")


def _rcs_dbsm(paths, R, depth=None):
    h = paths.coherent_sum(FC, depth)[0, 0]
    return 10 * np.log10(np.abs(h) ** 2 * (4 * np.pi) ** 3 * R ** 4 / LAM ** 2)


def _quad(corners):
    return trimesh.Trimesh(np.asarray(corners, float), [[0, 1, 2], [0, 2, 3]], process=False)


def test_01_pec_plate_normal_incidence_rcs():
    a, R = 0.1, 20.0
    p = render_reference({"plate": square_plate([R, 0, 0], a)}, {"plate": "metal"}, RADAR,
                         max_depth=1, **ISO)
    expected = 10 * np.log10(4 * np.pi * a ** 4 / LAM ** 2)
    assert abs(_rcs_dbsm(p, R) - expected) < 0.5


@pytest.mark.parametrize("deg", [0.2, 0.5, 1.56])
def test_02_plate_angular_pattern_is_sinc_squared(deg):
    """Main lobe and the first sidelobe peak (k a sin = 4.49) of a 0.1 m plate at 100 m."""
    a, R = 0.1, 100.0
    p = render_reference({"plate": square_plate([R, 0, 0], a, yaw_deg=deg)}, {"plate": "metal"},
                         RADAR, max_depth=1, **ISO)
    th = np.radians(deg)
    x = K * a * np.sin(th)
    expected = 4 * np.pi * a ** 4 / LAM ** 2 * np.cos(th) ** 2 * (np.sin(x) / x) ** 2
    assert abs(_rcs_dbsm(p, R) - 10 * np.log10(expected)) < 0.5


def _split(mesh, n):
    for _ in range(n):
        mesh = mesh.subdivide()
    return mesh


@pytest.mark.parametrize("subdiv", [0, 2])
def test_03_dihedral_on_bisector(subdiv):
    a = b = 0.1
    R = 30.0
    s2 = np.sqrt(0.5)
    O = np.array([R, 0, -b / 2])
    u1, u2, w = np.array([-s2, s2, 0]) * a, np.array([-s2, -s2, 0]) * a, np.array([0, 0, b])
    meshes = {"a": _split(_quad([O, O + u1, O + u1 + w, O + w]), subdiv),
              "b": _split(_quad([O, O + w, O + u2 + w, O + u2]), subdiv)}
    p = render_reference(meshes, {"a": "metal", "b": "metal"}, RADAR, max_depth=2, **ISO)
    expected = 10 * np.log10(8 * np.pi * a ** 2 * b ** 2 / LAM ** 2)
    assert abs(_rcs_dbsm(p, R) - expected) < 1.0
    assert _rcs_dbsm(p, R, depth=1) < expected - 20      # carried by the double bounce


@pytest.mark.parametrize("subdiv", [0, 2])
def test_04_trihedral_on_symmetry_axis(subdiv):
    a, R = 0.15, 30.0
    axis = np.ones(3) / np.sqrt(3)
    radar = RadarConfig.dense(1, 1, position=tuple(R * axis),
                              orientation=(np.radians(-135.0), np.arcsin(1 / np.sqrt(3)), 0.0))
    V = np.array([[0, 0, 0], [a, 0, 0], [0, a, 0], [0, 0, a]], float)
    faces = {f"f{i}": _split(trimesh.Trimesh(V, [f], process=False), subdiv)
             for i, f in enumerate(([0, 1, 2], [0, 2, 3], [0, 3, 1]))}
    p = render_reference(faces, dict.fromkeys(faces, "metal"), radar, max_depth=3, **ISO)
    expected = 10 * np.log10(4 * np.pi * a ** 4 / (3 * LAM ** 2))
    assert abs(_rcs_dbsm(p, R) - expected) < 1.0
    assert _rcs_dbsm(p, R, depth=3) > expected - 1.0 > _rcs_dbsm(p, R, depth=2) + 20
    assert p.info["chains"] >= 6                           # all six orders of the corner


def test_05_exact_per_pair_delays_of_a_point_like_plate():
    """A 4 mm plate: one path whose delay is (|x - tx_i| + |x - rx_j|) / c for every pair."""
    from sionna_mmir.radar.config import rotation_matrix

    radar = RadarConfig.awr1843(position=(0.3, -0.2, 1.1), orientation=(0.3, -0.1, 0.05))
    rot = rotation_matrix(radar.orientation)
    x = radar.position + rot @ np.array([3.0, 0.4, 0.2])
    plate = square_plate([0, 0, 0], 0.004)                  # faces -x
    to_radar = (radar.position - x) / np.linalg.norm(radar.position - x)
    plate.apply_transform(trimesh.geometry.align_vectors([-1.0, 0, 0], to_radar))
    plate.apply_translation(x)
    p = render_reference({"p": plate}, {"p": "metal"}, radar, max_depth=1, diffuse=False, **ISO)
    assert p.num_paths == 1
    tx = radar.position + radar.tx_positions @ rot.T
    rx = radar.position + radar.rx_positions @ rot.T
    d_t, d_r = np.linalg.norm(x - tx, axis=1), np.linalg.norm(x - rx, axis=1)
    exact = (d_t[:, None] + d_r[None, :]) / C
    np.testing.assert_allclose(p.tau[..., 0], exact, rtol=0, atol=2e-15)   # 0.6 um of path
    assert np.ptp(exact) > 1e-12                            # the pairs really differ
    # broadside to the array centre: |a| = |Gamma| A / (4 pi d_t d_r)
    np.testing.assert_allclose(np.abs(p.a[..., 0]), 0.004 ** 2 / (4 * np.pi * d_t[:, None] * d_r),
                               rtol=0.01)


def test_06_dielectric_half_space_and_slabs_scale_by_gamma_squared():
    a, R = 0.1, 20.0
    plate = {"plate": square_plate([R, 0, 0], a)}

    def rcs(material):
        return _rcs_dbsm(render_reference(plate, {"plate": material}, RADAR, max_depth=1,
                                          diffuse=False, **ISO), R)

    pec = rcs({"eps_real": 1.0, "eps_imag": 1e12})
    eps = 4.0
    r = (1 - np.sqrt(eps)) / (1 + np.sqrt(eps))
    assert abs(rcs({"eps_real": eps, "eps_imag": 0.0}) - pec - 20 * np.log10(abs(r))) < 0.1
    d_half = LAM / (2 * np.sqrt(eps))
    assert rcs({"eps_real": eps, "eps_imag": 0.0, "thickness": d_half}) < pec - 60
    quarter = rcs({"eps_real": eps, "eps_imag": 0.0, "thickness": d_half / 2})
    assert abs(quarter - pec - 20 * np.log10(2 * abs(r) / (1 + r * r))) < 0.1


def test_07_fresnel_brewster_angle_and_lossless_power():
    from sionna_mmir.independent.materials import fresnel_half_space, slab_reflection

    eps = 4.0
    th_b = np.arctan(np.sqrt(eps))
    r_s, r_p = fresnel_half_space(np.cos([th_b, 0.3, 1.2]), np.full(3, eps + 0j))
    assert abs(r_p[0]) < 1e-12 and abs(r_s[0]) > 0.3
    R_s, R_p = slab_reflection(np.cos([0.3, 1.2]), np.full(2, eps + 0j), 0.01, FC)
    assert np.all(np.abs(R_s) <= 1 + 1e-12) and np.all(np.abs(R_p) <= 1 + 1e-12)


def test_08_nothing_in_the_package_imports_the_model_it_scores():
    root = pathlib.Path(__file__).resolve().parents[1] / "sionna_mmir" / "independent"
    forbidden = ("sionna_mmir.paths", "sionna_mmir.bsdf", "mitsuba", "drjit")
    modules = sorted(root.glob("*.py"))
    assert len(modules) >= 10
    for path in modules:
        pkg = ["sionna_mmir", "independent"]
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = pkg[:len(pkg) - node.level + 1] if node.level else []
                mod = ".".join(base + ([node.module] if node.module else []))
                names = [mod] + [f"{mod}.{a.name}" for a in node.names]
            for n in names:
                assert not n.startswith(forbidden), f"{path.name} imports {n}"


def test_09_rendering_loads_no_model_module_at_run_time():
    code = ("import sys, numpy as np, trimesh\n"
            "sys.path.insert(0, 'tests')\n"
            "from helpers import square_plate\n"
            "from sionna_mmir.independent import render_reference, reference_truth\n"
            "from sionna_mmir.radar import RadarConfig\n"
            "r = RadarConfig.awr1843()\n"
            "p = render_reference({'p': square_plate([3, 0, 0], 0.2)}, {'p': 'glass'}, r, max_depth=2)\n"
            "p.adc(r)\n"
            "bad = [m for m in sys.modules if m.split('.')[0] in ('mitsuba', 'drjit')\n"
            "       or m.startswith(('sionna_mmir.paths', 'sionna_mmir.bsdf'))]\n"
            "assert not bad, bad\n")
    root = pathlib.Path(__file__).resolve().parents[1]
    subprocess.run([sys.executable, "-c", code], cwd=root, check=True, timeout=120)


def test_10_bad_input_raises_package_errors():
    good = square_plate([2, 0, 0], 0.2)
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    with pytest.raises(InputValueError, match="empty"):
        render_reference({"e": empty}, {"e": "metal"}, RADAR)
    nan = (np.array([[2, 0, 0], [2, 1, 0], [2, 0, np.nan]]), np.array([[0, 1, 2]]))
    with pytest.raises(InputValueError, match="NaN"):
        render_reference({"n": nan}, {"n": "metal"}, RADAR)
    with pytest.raises(InputValueError, match="non-empty"):
        render_reference({}, {}, RADAR)
    with pytest.raises(ConfigError, match="unobtainium"):
        render_reference({"p": good}, {"p": "unobtainium"}, RADAR)
    with pytest.raises(ConfigError, match="no material"):
        render_reference({"p": good}, {}, RADAR)
    with pytest.raises(ConfigError, match="brick"):
        render_reference({"p": good}, {"p": "brick"}, RADAR)          # 1-40 GHz only
    with pytest.raises(ConfigError, match="eps_real"):
        render_reference({"p": good}, {"p": {"eps": 3.0}}, RADAR)
    with pytest.raises(InputValueError, match="eps_imag >= 0"):
        render_reference({"p": good}, {"p": {"eps_real": 3.0, "eps_imag": -1.0}}, RADAR)
    for kw in ({"max_depth": 4}, {"max_depth": 0}, {"fresnel": 0.0}, {"tx_pattern": "dipole"},
               {"merge_fraction": -1.0}, {"min_rel_amplitude": 1.0}):
        with pytest.raises(ConfigError):
            render_reference({"p": good}, {"p": "metal"}, RADAR, **kw)


def test_11_rough_plate_coherent_part_follows_rayleigh_loss():
    a, R, sigma_h = 0.1, 20.0, 2e-4
    plate = {"plate": square_plate([R, 0, 0], a)}
    smooth = {"eps_real": 1.0, "eps_imag": 1e12}
    rough = dict(smooth, sigma_h=sigma_h, l_c=0.01)
    p0, p1 = (render_reference(plate, {"plate": m}, RADAR, max_depth=1, diffuse=False, **ISO)
              for m in (smooth, rough))
    loss = _rcs_dbsm(p1, R) - _rcs_dbsm(p0, R)
    assert abs(loss - 10 * np.log10(np.exp(-(2 * K * sigma_h) ** 2))) < 0.05


def test_12_kirchhoff_sigma0_matches_its_hankel_transform():
    """sigma0 = (k^2 / pi) |Gamma c|^2 e^{-g} 2 pi int (e^{g C(r)} - 1) J0(q_t r) r dr."""
    from scipy.integrate import quad
    from scipy.special import j0

    from sionna_mmir.independent.rough import kirchhoff_sigma0

    for sigma_h, l_c, theta in ((5e-4, 5e-3, 0.3), (1e-3, 8e-3, 0.6), (2e-4, 4e-3, 0.0)):
        q_z, q_t = 2 * K * np.cos(theta), 2 * K * np.sin(theta)
        g = (q_z * sigma_h) ** 2
        integrand = lambda r: (np.expm1(g * np.exp(-r * r / l_c ** 2))) * j0(q_t * r) * r  # noqa: E731
        val, _ = quad(integrand, 0, 8 * l_c, limit=400)
        expected = K ** 2 / np.pi * 0.25 * np.exp(-g) * 2 * np.pi * val
        got = kirchhoff_sigma0(K, [sigma_h], [l_c], [q_z], [q_t], [0.5])[0]
        assert abs(10 * np.log10(got / expected)) < 0.01, (got, expected)


def test_13_incoherent_term_has_the_power_of_sigma0():
    """Mean over seeds of the diffuse power of a rough plate at 35 deg = sigma0 A (radar eq.)."""
    from sionna_mmir.independent.materials import copol_reflection
    from sionna_mmir.independent.rough import kirchhoff_sigma0

    R, a, th = 3.0, 0.3, np.radians(35.0)
    mat = {"eps_real": 5.0, "eps_imag": 0.3, "sigma_h": 6e-4, "l_c": 5e-3}
    plate = {"p": square_plate([R, 0, 0], a, yaw_deg=35.0)}
    coh = render_reference(plate, {"p": mat}, RADAR, max_depth=1, diffuse=False, **ISO)
    powers = [np.abs(render_reference(plate, {"p": mat}, RADAR, max_depth=1, seed=s,
                                      **ISO).coherent_sum(FC) - coh.coherent_sum(FC))[0, 0] ** 2
              for s in range(64)]
    params = np.array([[5.0, 0.3, 6e-4, 5e-3, 1.0, np.inf]])
    gamma = copol_reflection(np.array([np.cos(th)]), params, FC)
    s0 = kirchhoff_sigma0(K, [6e-4], [5e-3], [2 * K * np.cos(th)], [2 * K * np.sin(th)],
                          gamma * np.cos(th))[0]
    expected = LAM ** 2 * s0 * a * a / ((4 * np.pi) ** 3 * R ** 4)
    assert abs(10 * np.log10(np.mean(powers) / expected)) < 1.5


def test_14_near_field_plate_matches_brute_force_physical_optics():
    """A 0.4 m plate at 1.5 m (tens of Fresnel zones) against a 0.5 mm midpoint sum."""
    R, a, h = 1.5, 0.4, 5e-4
    p = render_reference({"p": square_plate([R, 0, 0], a)}, {"p": {"eps_real": 1.0, "eps_imag": 1e12}},
                         RADAR, max_depth=1, diffuse=False, **ISO)
    s = np.arange(-a / 2 + h / 2, a / 2, h)
    tot = 0j
    for ys in np.array_split(s, 8):
        Y, Z = np.meshgrid(ys, s, indexing="ij")
        d = np.sqrt(R * R + Y * Y + Z * Z)
        tot += np.sum((R / d) * np.exp(-2j * K * d) / d ** 2) * h * h
    brute = np.conj(-1j / (4 * np.pi) * tot)                 # beat convention, Gamma = -1
    got = p.coherent_sum(FC)[0, 0]
    assert abs(got - brute) < 0.03 * abs(brute)


def test_15_double_bounce_matches_brute_force_image_theory_in_the_near_field():
    """90 deg dihedral of 0.3 m plates at 2 m: depth-2 paths vs a direct image-theory sum."""
    R, a, h = 2.0, 0.3, 5e-4
    s2 = np.sqrt(0.5)
    O = np.array([R, 0.0, -a / 2])
    u1, u2, w = np.array([-s2, s2, 0]) * a, np.array([-s2, -s2, 0]) * a, np.array([0, 0, a])
    meshes = {"a": _quad([O, O + u1, O + u1 + w, O + w]), "b": _quad([O, O + w, O + u2 + w, O + u2])}
    pec = {"eps_real": 1.0, "eps_imag": 1e12}
    p = render_reference(meshes, {"a": pec, "b": pec}, RADAR, max_depth=2, diffuse=False, **ISO)
    n = int(round(a / h))
    t = (np.arange(n) + 0.5) / n
    U, V = (g.ravel() for g in np.meshgrid(t, t, indexing="ij"))
    total = 0j
    for uA, uB in ((u1, u2), (u2, u1)):
        nA = np.cross(uA, w) / np.linalg.norm(np.cross(uA, w))
        nB = np.cross(uB, w) / np.linalg.norm(np.cross(uB, w))
        img = -2 * np.dot(-O, nB) * nB                      # radar (origin) mirrored in B
        y = O + U[:, None] * uA + V[:, None] * w
        d2 = img - y
        L2 = np.linalg.norm(d2, axis=1)
        s = np.dot(O - y, nB) / (d2 @ nB / L2)
        hit = y + s[:, None] * d2 / L2[:, None] - O
        ok = (s > 0) & (s < L2) & (hit @ uB >= 0) & (hit @ uB <= a * a) & (hit @ w >= 0) & (hit @ w <= a * a)
        L1 = np.linalg.norm(y, axis=1)
        c_po = 0.5 * (np.abs(y @ nA) / L1 + np.abs(d2 @ nA) / L2)
        total += np.sum((c_po * np.exp(-1j * K * (L1 + L2)) / (L1 * L2))[ok]) * (a / n) ** 2
    brute = np.conj(1j / (4 * np.pi) * total)               # Gamma^2 = +1
    got = p.coherent_sum(FC, depth=2)[0, 0]
    assert abs(20 * np.log10(abs(got) / abs(brute))) < 0.5


def test_16_occluder_and_visibility_backends_agree():
    plates = {"front": square_plate([2.0, 0.1, 0.0], 0.1), "back": square_plate([3.0, 0.0, 0.0], 0.5)}
    mats = dict.fromkeys(plates, "metal")
    hidden = render_reference(plates, mats, RADAR, max_depth=1, diffuse=False, **ISO)
    alone = [render_reference({n: plates[n]}, {n: "metal"}, RADAR, max_depth=1, diffuse=False,
                              **ISO).info["subfacets"][0] for n in plates]
    assert hidden.info["subfacets"][0] < sum(alone) - 20            # the shadowed cells are gone
    numpy_vis = render_reference(plates, mats, RADAR, max_depth=1, diffuse=False, use_embree=False,
                                 **ISO)
    assert numpy_vis.info["subfacets"] == hidden.info["subfacets"]
    np.testing.assert_allclose(numpy_vis.coherent_sum(FC), hidden.coherent_sum(FC), rtol=1e-6)


def test_17_reference_truth_is_a_capture_with_the_benchmark_noise_floor():
    from sionna_mmir.captures import Capture
    from sionna_mmir.independent import reference_truth
    from sionna_mmir.benchmark_scenes.catalog import SceneSpec

    spec = SceneSpec(name="tiny", objects={"wall": square_plate([3.0, 0, 1.0], 1.0, subdiv=1),
                                           "box": square_plate([2.5, 0.6, 1.2], 0.2)},
                     materials={"wall": "concrete", "box": "metal"},
                     radar_position=np.array([0.0, 0.0, 1.0]), radar_orientation=np.zeros(3),
                     description="a wall and a plate")
    radar = RadarConfig.awr1843(position=(0.0, 0.0, 1.0))
    cap = reference_truth(spec, radar, seed=3)
    assert isinstance(cap, Capture) and cap.frames.shape == (1,) + radar.adc_shape
    assert cap.metadata["renderer"].endswith("render_reference") and cap.metadata["seed"] == 3
    clean = reference_truth(spec, radar, seed=3, noise_db=-300.0).adc
    noise = cap.adc - clean
    rel = np.mean(np.abs(noise) ** 2) / np.abs(clean).max() ** 2
    assert abs(10 * np.log10(rel) + 40.0) < 0.5
    with pytest.raises(ConfigError, match="seed"):
        reference_truth(spec, radar, seed=-1)


def test_18_merged_paths_reproduce_the_adc_of_one_path_per_subfacet():
    """Delay-grid merging: same ADC (to -40 dB of its peak) with far fewer paths."""
    radar = RadarConfig.awr1843()
    plates = {"a": square_plate([3.0, 0.0, 0.0], 0.5), "b": square_plate([2.5, 0.6, 0.1], 0.5, yaw_deg=30)}
    mats = {"a": "metal", "b": "concrete"}
    merged, single = (render_reference(plates, mats, radar, max_depth=1, merge_fraction=mf,
                                       min_rel_amplitude=0.0) for mf in (0.1, 0.0))
    assert merged.num_paths < single.num_paths / 4
    a, b = merged.adc(radar), single.adc(radar)
    assert np.abs(a - b).max() < 1e-2 * np.abs(b).max()
    np.testing.assert_allclose(merged.coherent_sum(radar.center_frequency),
                               single.coherent_sum(radar.center_frequency), rtol=1e-5)


def test_19_simplex_exponential_matches_quadrature():
    from sionna_mmir.independent.quadrature import simplex_exp, subdivide

    t1 = np.array([0.0, 1e-5, 1e-3, 0.5, 3.0, 20.0, 20.0, 7.0])
    t2 = np.array([0.0, 0.0, 1e-3 + 1e-6, -0.4, 3.0 + 5e-5, -15.0, 20.00001, 7.0])
    sub, _ = subdivide(np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]]), np.array([300]))
    c = sub.mean(axis=1)
    num = np.array([np.mean(np.exp(-1j * (a * c[:, 0] + b * c[:, 1]))) / 2 for a, b in zip(t1, t2)])
    np.testing.assert_allclose(simplex_exp(t1, t2), num, atol=1e-5)


def test_20_pruning_drops_only_weak_paths(monkeypatch):
    """A 1 cm plate next to a 0.5 m plate: its paths fall below -40 dB and go, whole chunks too."""
    from sionna_mmir.independent import accumulate

    monkeypatch.setattr(accumulate, "_CHUNK", 64)           # many chunks, some entirely weak
    plates = {"big": square_plate([3.0, 0.0, 0.0], 0.5), "left": square_plate([6.0, 1.0, 0.5], 0.01),
              "right": square_plate([6.0, -1.0, -0.5], 0.01)}
    mats = dict.fromkeys(plates, "metal")
    full = render_reference(plates, mats, RADAR, max_depth=2, min_rel_amplitude=0.0, **ISO)
    for rel in (1e-3, 0.2):                                  # 0.2 empties whole chunks
        pruned = render_reference(plates, mats, RADAR, max_depth=2, min_rel_amplitude=rel, **ISO)
        assert 0 < pruned.num_paths < full.num_paths
        kept = np.abs(pruned.a).max(axis=(0, 1))
        assert kept.min() >= rel * np.abs(full.a).max() * (1 - 1e-5)
    pruned = render_reference(plates, mats, RADAR, max_depth=2, min_rel_amplitude=1e-3, **ISO)
    h_full, h_pruned = full.coherent_sum(FC), pruned.coherent_sum(FC)
    assert np.abs(h_full - h_pruned).max() < 0.05 * np.abs(h_full).max()
