"""The plain Sionna RT baseline (:class:`sionna_mmir.baseline.sionna_rt.SionnaBaseline`).

Unmodified Sionna RT 2.2 on the same scene and radar: per-object ITU
materials, one Sionna Transmitter / Receiver per radar element, Sionna's
``PathSolver`` (evaluated loops, deterministic), paths -> ADC through
:func:`sionna_mmir.fmcw.synthesize_adc`.  Small AWR1843 set-ups (3 Tx x 4 Rx,
64 samples) and 20k rays per source keep the file well under a minute on 2
CPU cores.
"""
from __future__ import annotations

import dataclasses
import importlib.util
import json
import pathlib

import numpy as np
import pytest
import trimesh

import sionna_mmir  # noqa: F401  (configures LLVM before Dr.Jit starts)
from sionna_mmir.utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from sionna_mmir.baseline.sionna_rt import PARAM_NAMES, SionnaBaseline  # noqa: E402
from sionna_mmir.errors import ConfigError, InputValueError  # noqa: E402
from sionna_mmir.fmcw.synthesize import synthesize_adc  # noqa: E402
from sionna_mmir.paths.render import to_numpy  # noqa: E402
from sionna_mmir.processing.drjit_ra import ra_loss_from_adc  # noqa: E402
from sionna_mmir.processing.imaging import range_azimuth  # noqa: E402
from sionna_mmir.radar.config import RadarConfig, rotation_matrix  # noqa: E402

C = 299_792_458.0
SPECULAR, NONE = 1, 0          # sionna.rt.constants.InteractionType
RAYS = 20_000
REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]


def _radar(**kw):
    return dataclasses.replace(RadarConfig.awr1843(), num_samples=64, **kw)


def _plate(centre, size, yaw=0.0):
    """Square plate of side ``size`` [m] facing the origin along ``-x`` rotated by ``yaw``."""
    v = np.array([[0, -1, -1], [0, 1, -1], [0, 1, 1], [0, -1, 1]], float) * size / 2
    m = trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)
    m.apply_transform(trimesh.transformations.rotation_matrix(yaw, [0, 0, 1]))
    m.apply_translation(centre)
    return m


def _specular_taus(bl, paths):
    """Delay [s] of the single first-order specular path of every (tx, rx) pair."""
    it = paths.interactions.numpy()                    # [depth, rx, 1, tx, 1, P]
    valid = paths.valid.numpy()                        # [rx, 1, tx, 1, P]
    tau = paths.tau.numpy()
    first = valid & (it[0] == SPECULAR) & np.all(it[1:] == NONE, axis=0)
    out = np.full((bl.radar.num_tx, bl.radar.num_rx), np.nan)
    for t in range(bl.radar.num_tx):
        for r in range(bl.radar.num_rx):
            sel = first[r, 0, t, 0]
            # the same specular path may be found through both coplanar triangles
            vals = np.unique(np.round(tau[r, 0, t, 0][sel] * C, 7))
            assert len(vals) == 1, f"pair ({t}, {r}): specular path lengths {vals}"
            out[t, r] = vals[0] / C
    return out


def _mirror_lengths(tx, rx, centre, normal):
    """Exact specular path lengths ``|mirror(tx) - rx|`` off the plane (centre, normal)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    img = tx - 2.0 * ((tx - centre) @ n)[:, None] * n[None, :]
    return np.linalg.norm(img[:, None, :] - rx[None, :, :], axis=-1)


AZ = np.radians(15.0)
CENTRE = 3.0 * np.array([np.cos(AZ), np.sin(AZ), 0.0])


@pytest.fixture(scope="module")
def plate_run():
    radar = _radar()
    bl = SionnaBaseline({"plate": _plate(CENTRE, 0.5, AZ)}, {"plate": "metal"}, radar,
                        samples_per_src=RAYS)
    adc = bl.render()
    return bl, adc, bl.last_paths


# ---------------------------------------------------------------- 01 geometry
def test_01_metal_plate_peak_and_exact_pair_delays(plate_run):
    bl, adc, paths = plate_run
    radar = bl.radar
    x = to_numpy(adc)
    assert x.shape == radar.adc_shape and np.all(np.isfinite(x)) and np.abs(x).max() > 0
    ra, ranges, az = range_azimuth(x, radar)
    i, j = np.unravel_index(np.argmax(ra), ra.shape)
    assert abs(ranges[i] - 3.0) <= 1.0 * radar.range_resolution
    assert abs(np.degrees(az[j]) - 15.0) < 3.0

    # every pair has its own exact specular delay (no synthetic-array phase shifts)
    tau = _specular_taus(bl, paths)
    exact = _mirror_lengths(radar.tx_positions, radar.rx_positions, CENTRE,
                            -np.array([np.cos(AZ), np.sin(AZ), 0.0])) / C
    np.testing.assert_allclose(tau * C, exact * C, rtol=0, atol=2e-5)    # 20 um
    spread = (exact - exact.mean()) * C                                # mm-scale MIMO spread
    assert np.ptp(spread) > 1e-3
    np.testing.assert_allclose((tau - tau.mean()) * C, spread, rtol=0, atol=2e-5)
    # ~2R/c
    assert abs(tau.mean() * C / 2 - 3.0) < 0.01


def test_01b_radar_pose_moves_the_elements():
    """Same plate in the radar frame, radar moved and turned: the same delays."""
    pos, ori = np.array([1.0, -2.0, 0.5]), np.array([np.radians(30), np.radians(5), 0.0])
    radar = _radar(position=pos, orientation=ori)
    rot = rotation_matrix(ori)
    plate = _plate(CENTRE, 0.5, AZ)
    plate = trimesh.Trimesh(plate.vertices @ rot.T + pos, plate.faces, process=False)
    bl = SionnaBaseline({"plate": plate}, {"plate": "metal"}, radar, samples_per_src=RAYS,
                        diffuse_reflection=False, max_depth=1)
    np.testing.assert_allclose(bl.tx_scene_positions, radar.tx_positions @ rot.T + pos, atol=1e-12)
    bl.render()
    tau = _specular_taus(bl, bl.last_paths)
    exact = _mirror_lengths(radar.tx_positions, radar.rx_positions, CENTRE,
                            -np.array([np.cos(AZ), np.sin(AZ), 0.0])) / C
    np.testing.assert_allclose(tau * C, exact * C, rtol=0, atol=2e-5)


# ----------------------------------------------------------- 02 phase / ADC
def test_02_phase_convention_single_specular_path():
    radar = _radar()
    bl = SionnaBaseline({"plate": _plate(CENTRE, 0.5, AZ)}, {"plate": "concrete"}, radar,
                        max_depth=1, samples_per_src=RAYS, diffuse_reflection=False,
                        diffraction=False)
    x = to_numpy(bl.render())
    paths = bl.last_paths
    # Sionna's own arrays, [rx, 1, tx, 1, P] -> [tx, rx, P], invalid -> 0
    valid = np.transpose(paths.valid.numpy()[:, 0, :, 0, :], (1, 0, 2))
    a_s = np.transpose((paths.a[0].numpy() + 1j * paths.a[1].numpy())[:, 0, :, 0, :], (1, 0, 2))
    tau = np.transpose(paths.tau.numpy()[:, 0, :, 0, :], (1, 0, 2))
    a_s, tau = np.where(valid, a_s, 0), np.where(valid, tau, 0)
    assert np.all(np.abs(a_s).max(axis=-1) > 0)         # one specular path per pair

    ref = synthesize_adc(radar, np.conj(a_s), tau)       # the package's NumPy path
    scale = np.abs(ref).max()
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-4 * scale)

    # independent: s[k] = conj(h(f_k)) with Sionna's h(f) = sum a_s exp(-j 2 pi f tau)
    fk = radar.start_frequency + radar.slope * radar.sample_times()
    h = np.sum(a_s[..., None].astype(np.complex128)
               * np.exp(-2j * np.pi * fk[None, None, None, :] * tau[..., None].astype(np.float64)),
               axis=2)
    np.testing.assert_allclose(x[:, :, 0, :], np.conj(h), rtol=0, atol=1e-4 * scale)

    # Sionna's own Paths.cfr at baseband f_k - f_c (passband = a_s exp(-j2pi(f_c + f) tau))
    re, im = paths.cfr(mi.Float((fk - bl.frequency).astype(np.float32)), normalize_delays=False)
    hs = re.numpy() + 1j * im.numpy()                    # [rx, 1, tx, 1, time, K]
    hs = np.transpose(hs[:, 0, :, 0, 0, :], (1, 0, 2))
    np.testing.assert_allclose(x[:, :, 0, :], np.conj(hs), rtol=0, atol=5e-3 * scale)

    # and the benchmark adapter (Sionna's Paths.cfr fed our paths), if importable
    if _benchmarks_on_path():
        from benchmarks.sionna_cfr import sionna_beat_signal
        np.testing.assert_allclose(x, sionna_beat_signal(radar, np.conj(a_s), tau),
                                   rtol=0, atol=5e-3 * scale)


def _benchmarks_on_path() -> bool:
    """True when this checkout's ``benchmarks/`` is importable as ``benchmarks``."""
    spec = importlib.util.find_spec("benchmarks")
    if spec is None or not (REPO_ROOT / "benchmarks" / "sionna_cfr.py").is_file():
        return False
    where = [pathlib.Path(p).resolve() for p in (spec.submodule_search_locations or [])]
    return (REPO_ROOT / "benchmarks").resolve() in where


# -------------------------------------------------------------- 03 gradients
@pytest.fixture(scope="module")
def two_plates():
    radar = _radar()
    a1, a2 = np.radians(20), np.radians(-20)
    meshes = {"metal": _plate(3.0 * np.array([np.cos(a1), np.sin(a1), 0]), 0.5, a1),
              "wall": _plate(4.0 * np.array([np.cos(a2), np.sin(a2), 0]), 0.8, a2)}
    target = SionnaBaseline(meshes, {"metal": "metal", "wall": "wood"}, radar,
                            samples_per_src=RAYS)
    ra_target, _, _ = range_azimuth(to_numpy(target.render()), radar)
    bl = SionnaBaseline(meshes, {"metal": "metal", "wall": "concrete"}, radar,
                        samples_per_src=RAYS)
    return bl, ra_target


@pytest.mark.parametrize("key,step", [("wall.conductivity", 0.05),
                                      ("wall.relative_permittivity", 0.02)])
def test_03_ra_loss_gradient_vs_finite_differences(two_plates, key, step):
    bl, ra_target = two_plates
    radar = bl.radar
    l0 = bl.params()[key][0]

    def loss(value, grad=False):
        lat = mi.Float(value)
        if grad:
            dr.enable_grad(lat)
        bl.apply({key: lat})
        out = ra_loss_from_adc(bl.render(), radar, ra_target)   # same seed every time
        if grad:
            dr.backward(out)
            return float(out[0]), float(dr.grad(lat)[0])
        return float(out[0])

    try:
        value, ad = loss(l0, grad=True)
        fd = (loss(l0 + step) - loss(l0 - step)) / (2 * step)
    finally:
        bl.apply({key: mi.Float(l0)})
    assert value > 0 and abs(fd) > 0
    rel = abs(ad - fd) / abs(fd)
    print(f"{key}: loss {value:.4e}, AD {ad:+.5e}, FD {fd:+.5e}, rel. error {rel:.2%}")
    assert rel < 0.05


def test_03b_params_apply_round_trip(two_plates):
    bl, _ = two_plates
    lat = bl.params()
    assert set(lat) == {f"{o}.{p}" for o in ("metal", "wall") for p in PARAM_NAMES}
    before = bl.values()
    bl.apply(lat)
    after = bl.values()
    for k in before:
        assert after[k] == pytest.approx(before[k], rel=1e-5)
    assert after["metal.conductivity"] == pytest.approx(1e7, rel=1e-5)
    assert after["wall.relative_permittivity"] == pytest.approx(5.24, rel=1e-5)
    assert after["wall.conductivity"] == pytest.approx(0.0462 * 77 ** 0.7822, rel=1e-4)
    assert after["wall.scattering_coefficient"] == pytest.approx(0.3, rel=1e-5)
    assert after["wall.thickness"] == pytest.approx(0.2, rel=1e-5)
    # the latent maps: eps_r = 1 + exp(l), S = sigmoid(l)
    bl.apply({"wall.relative_permittivity": mi.Float(np.log(2.0)),
              "wall.scattering_coefficient": mi.Float(0.0)})
    try:
        v = bl.values()
        assert v["wall.relative_permittivity"] == pytest.approx(3.0, rel=1e-6)
        assert v["wall.scattering_coefficient"] == pytest.approx(0.5, rel=1e-6)
        # set_values: physical values in, the same values out (metal's eps_r = 1 floored)
        bl.set_values({"wall.relative_permittivity": 4.1, "wall.conductivity": 2.5,
                       "wall.thickness": 0.15, "metal.relative_permittivity": 1.0})
        v = bl.values()
        assert v["wall.relative_permittivity"] == pytest.approx(4.1, rel=1e-6)
        assert v["wall.conductivity"] == pytest.approx(2.5, rel=1e-6)
        assert v["wall.thickness"] == pytest.approx(0.15, rel=1e-6)
        assert v["metal.relative_permittivity"] == pytest.approx(1.0, abs=2e-6)
        assert v["wall.scattering_coefficient"] == pytest.approx(0.5, rel=1e-6)   # untouched
        with pytest.raises(InputValueError, match="unknown parameter"):
            bl.set_values({"wall.roughness": 1.0})
    finally:
        bl.apply(lat)


# ------------------------------------------------------------ 04 bad input
def test_04_bad_input_errors(tmp_path):
    radar = _radar()
    good = _plate(CENTRE, 0.5, AZ)
    with pytest.raises(ConfigError, match="unobtainium"):
        SionnaBaseline({"p": good}, {"p": "unobtainium"}, radar)
    with pytest.raises(ConfigError, match="brick.*77 GHz"):
        SionnaBaseline({"p": good}, {"p": "brick"}, radar)      # ITU row ends at 40 GHz
    with pytest.raises(InputValueError, match="meshes is empty"):
        SionnaBaseline({}, {}, radar)
    with pytest.raises(ConfigError, match="no material given.*'p'"):
        SionnaBaseline({"p": good}, {}, radar)
    with pytest.raises(ConfigError, match="unknown object.*'q'"):
        SionnaBaseline({"p": good}, {"p": "metal", "q": "wood"}, radar)
    bad = trimesh.Trimesh(np.array(good.vertices), np.array(good.faces), process=False)
    v = np.array(bad.vertices)
    v[1, 2] = np.nan
    bad = trimesh.Trimesh(v, np.array(good.faces), process=False)
    with pytest.raises(InputValueError, match=r"object 'p'.*NaN"):
        SionnaBaseline({"p": bad}, {"p": "metal"}, radar)
    with pytest.raises(InputValueError, match="does not exist"):
        SionnaBaseline({"p": tmp_path / "missing.ply"}, {"p": "metal"}, radar)
    with pytest.raises(ConfigError, match="max_depth"):
        SionnaBaseline({"p": good}, {"p": "metal"}, radar, max_depth=0)
    with pytest.raises(ConfigError, match="scattering_coefficient"):
        SionnaBaseline({"p": good}, {"p": "metal"}, radar, scattering_coefficient=1.5)


def test_04b_apply_rejects_unknown_keys_and_nan(plate_run):
    bl = plate_run[0]
    with pytest.raises(InputValueError, match="unknown parameter 'plate.roughness'"):
        bl.apply({"plate.roughness": mi.Float(0.0)})
    with pytest.raises(InputValueError, match="not finite"):
        bl.apply({"plate.conductivity": mi.Float(float("nan"))})


# --------------------------------------------------------------- 05 describe
def test_05_describe_lists_the_exact_settings(plate_run):
    bl = plate_run[0]
    d = bl.describe()
    json.dumps(d)                                       # README-ready, plain types
    s = d["solver"]
    assert s["loop_mode"] == "evaluated" and s["synthetic_array"] is False and s["los"] is False
    assert (s["max_depth"], s["samples_per_src"], s["seed"]) == (3, RAYS, 0)
    assert s["diffuse_reflection"] and s["specular_reflection"] and s["diffraction"]
    assert not s["refraction"]
    assert d["antennas"]["num_tx"] == 3 and d["antennas"]["num_rx"] == 4
    assert d["materials"]["plate"]["itu"] == "metal"
    assert d["materials"]["plate"]["source"] == "sionna.rt.ITURadioMaterial"
    assert set(d["learnable"]) == set(PARAM_NAMES)
