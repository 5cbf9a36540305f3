"""The independent undeclared-effect generator (:mod:`sionna_mmir.independent.undeclared`).

Every check reads the generated ADC with its own plain processing (Hann-
windowed DTFTs at the known beat frequencies, matched steering, FFTs) and
compares with the drawn truth.  Cases share the room, clutter and thermal
noise of their seed, so ``case - clean`` isolates the planted effect.
"""
from __future__ import annotations

import ast
import functools
import json
import math
import pathlib
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh

from sionna_mmir.captures.coloradar import read_coloradar_run
from sionna_mmir.errors import InputValueError
from sionna_mmir.independent import undeclared as und
from sionna_mmir.independent import undeclared_adc as adc
from sionna_mmir.independent import undeclared_effects as fx

C = 299_792_458.0
PKG = pathlib.Path(und.__file__).parent
REPO = PKG.parents[1]
FORBIDDEN = ("sionna_mmir.paths", "sionna_mmir.bsdf", "sionna_mmir.fmcw", "sionna_mmir.effects",
             "sionna_mmir.residual", "mitsuba", "drjit", "sionna.")
ALLOWED_PACKAGE = ("sionna_mmir.radar", "sionna_mmir.captures", "sionna_mmir.errors",
                   "sionna_mmir.independent")


@functools.lru_cache(maxsize=None)
def case(kind):
    return und.make_case(kind, radar="awr1843")


def dtft(x, f, fs):
    """Hann-windowed DTFT of the last axis at frequency ``f`` [Hz]."""
    k = np.arange(x.shape[-1])
    return (np.hanning(x.shape[-1]) * x * np.exp(-2j * np.pi * f / fs * k)).sum(-1)


def corners(c):
    """``(positions relative to the radar [n, 3], ranges [n], beat frequencies [n])``."""
    r = c.radar_nominal
    p = np.array([k["centre_m"] for k in c.truth["corners"]]) - r.position
    rng = np.linalg.norm(p, axis=1)
    return p, rng, 2 * rng * r.slope / C


def strongest(c):
    p, rng, fb = corners(c)
    k = c.truth["strongest_corner"]
    return p[k], rng[k], fb[k]


def profile(x, pad=1):
    """Hann range profile power ``[pad N]`` averaged over all other axes."""
    n = x.shape[-1]
    return (np.abs(np.fft.fft(x * np.hanning(n), pad * n, axis=-1)) ** 2).reshape(
        -1, pad * n).mean(0)


def _imports(path):
    """Absolute module names imported by a module of sionna_mmir.independent."""
    here = ["sionna_mmir", "independent"]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = here[:len(here) + 1 - node.level] if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            out.append(mod)
            if not node.module:
                out += [f"{mod}.{a.name}" for a in node.names]
    return out


def test_01_imports_are_independent():
    files = sorted(PKG.glob("undeclared*.py")) + [PKG / "__init__.py"]
    assert len(files) >= 5
    for path in files:
        for name in _imports(path):
            assert not name.startswith(FORBIDDEN) and name not in ("sionna", "mitsuba", "drjit"), \
                (path.name, name)
            if name.startswith("sionna_mmir"):
                assert name.startswith(ALLOWED_PACKAGE), (path.name, name)
    code = ("import sys; from sionna_mmir.independent.undeclared import make_case; "
            "make_case('phase_noise', radar='awr1843', num_chirps=2, num_samples=64); "
            f"bad = [m for m in sys.modules if m.startswith({FORBIDDEN!r}) "
            "or m in ('sionna', 'mitsuba', 'drjit')]; print(bad); assert not bad")
    run = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def test_02_clean_peaks_at_corner_ranges_and_azimuths():
    c = case("clean")
    r, x = c.radar_nominal, c.capture.adc
    assert c.effects == () and c.capture.frames.shape == (1, 3, 4, 8, 128)
    assert c.capture.frames.dtype == np.complex64 and 2 <= len(c.truth["corners"]) <= 4
    pad = 16
    prof = profile(x, pad)
    virt = r.tx_positions[:, None] + r.rx_positions[None]
    flat = np.abs(virt[..., 2]) < 1e-9
    lam = C / r.center_frequency
    az = np.radians(np.arange(-80, 80, 0.05))
    for p, rng, fb in zip(*corners(c)):
        true_bin = rng / r.range_resolution
        lo, hi = int((true_bin - 2) * pad), int((true_bin + 2) * pad)
        peak = (lo + np.argmax(prof[lo:hi])) / pad
        assert abs(peak - true_bin) < 0.5, (rng, peak, true_bin)
        z = dtft(x, fb, r.sample_rate).mean(-1)[flat]
        steer = np.exp(-2j * np.pi * np.outer(np.sin(az), virt[..., 1][flat]) / lam)
        est = np.degrees(az[np.argmax(np.abs(np.conj(steer) @ z))])
        assert abs(est - np.degrees(np.arctan2(p[1], p[0]))) < 1.0, (rng, est)


def test_03_per_pair_delays_are_exact():
    r = und._radar("awr1843", 2, 64)
    q = r.position + np.array([0.9, 0.35, 0.2])               # ~1 m, off axis and elevated
    paths = adc.PointPaths(q[None], q[None], np.array([1.0 + 0j]))
    t = r.sample_times()
    x = adc.render(r, [paths], adc.Motion(r.position, np.eye(3)), t,
                   r.chirp_start_times()[None])[0]
    tx, rx = r.tx_positions + r.position, r.rx_positions + r.position
    d_t = np.linalg.norm(q - tx, axis=1)
    d_r = np.linalg.norm(q - rx, axis=1)
    tau = (d_t[:, None] + d_r[None]) / C
    for k in (0, 37, 63):
        want = 2 * np.pi * (r.start_frequency + r.slope * t[k]) * tau
        err = np.angle(x[:, :, 0, k] * np.exp(-1j * want))
        assert np.abs(err).max() < 2e-3, (k, err)
    gain = lambda d: 6.0 * np.clip(d @ np.array([1.0, 0, 0]), 0, None) ** 2
    amp = np.sqrt(gain((q - tx) / d_t[:, None])[:, None] * gain((q - rx) / d_r[:, None])[None]
                  ) / (d_t[:, None] * d_r[None])
    np.testing.assert_allclose(np.abs(x[:, :, 1, 5]), amp, rtol=1e-5)
    u = (q - r.position) / np.linalg.norm(q - r.position)
    far = 2 * np.linalg.norm(q - r.position) - (r.tx_positions[:, None] + r.rx_positions[None]) @ u
    near_field = 2 * np.pi * r.start_frequency * np.abs(tau - far / C)
    assert near_field.max() > 0.05            # a plane-wave model would fail the check above


def test_04_if_filter_attenuates_by_its_response():
    c, c0 = case("if_filter"), case("clean")
    p, fs = c.truth["effects"]["if_filter"], c.radar_nominal.sample_rate
    tol = np.array(p["rx_tolerance"])
    _, rng, fbs = corners(c)
    for fb in fbs:
        ratio = (dtft(c.capture.adc, fb, fs) / dtft(c0.capture.adc, fb, fs)).mean(axis=(0, 2))
        want = np.array([fx.hpf_response(fb, np.array(p["corners_hz"]) * tol[j])
                         for j in range(4)])
        np.testing.assert_allclose(20 * np.log10(np.abs(ratio)), 20 * np.log10(np.abs(want)),
                                   atol=0.05)
        np.testing.assert_allclose(np.angle(ratio / want), 0, atol=0.01)
    assert 20 * np.log10(np.abs(fx.hpf_response(fbs.min(), p["corners_hz"]))) < -0.3


def test_05_iq_imbalance_image_at_negative_beat_frequency():
    c, c0 = case("iq_imbalance"), case("clean")
    p, fs = c.truth["effects"]["iq_imbalance"], c.radar_nominal.sample_rate
    _, _, fb = strongest(c)
    g = 10 ** (np.array(p["gain_db"]) / 20)
    cp = np.cos(np.radians(p["phase_deg"]))
    want = 10 * np.log10((1 + g * g - 2 * g * cp) / (1 + g * g + 2 * g * cp))
    assert np.all((want > -30) & (want < -15))
    for x, expect in ((c.capture.adc, want), (c0.capture.adc, None)):
        img = np.abs(dtft(x, -fb, fs)).mean(axis=(0, 2)) / np.abs(dtft(x, fb, fs)).mean(axis=(0, 2))
        if expect is None:
            assert np.all(20 * np.log10(img) < want - 15)
        else:
            np.testing.assert_allclose(20 * np.log10(img), expect, atol=0.5)


def test_06_dc_offset_in_bin_zero():
    c, c0 = case("dc_offset"), case("clean")
    d = np.fft.fft(c.capture.adc - c0.capture.adc, axis=-1)
    assert (np.abs(d[..., 0]) ** 2).sum() / (np.abs(d) ** 2).sum() > 0.999999
    dc = np.array(c.truth["effects"]["dc_offset"]["rx_counts"])
    want = 128 * (dc[:, 0] + 1j * dc[:, 1])
    np.testing.assert_allclose(d[..., 0], np.broadcast_to(want[None, :, None], d.shape[:-1]),
                               rtol=1e-4)


def test_07_coupling_at_its_range():
    c, c0 = case("coupling"), case("clean")
    p, r = c.truth["effects"]["coupling"], c.radar_nominal
    prof = profile(c.capture.adc - c0.capture.adc)
    top = int(math.ceil((p["bounce_range_m"] + 0.1) / r.range_resolution))
    near = np.r_[0:top + 2, r.num_samples - 2:r.num_samples]
    assert np.argmax(prof) <= top
    assert prof[near].sum() / prof.sum() > 0.99
    level = 10 * np.log10(prof.max() / profile(c0.capture.adc)[
        int(round(strongest(c)[1] / r.range_resolution))])
    assert p["level_db"] - 8 < level < p["level_db"] + 6


def test_08_chirp_nonlinearity_smears_far_more_than_near():
    c, c0 = case("chirp_nonlinearity"), case("clean")
    fs = c.radar_nominal.sample_rate
    _, rng, fbs = corners(c)
    rel = np.array([np.abs(dtft(c.capture.adc - c0.capture.adc, f, fs)).mean()
                    / np.abs(dtft(c0.capture.adc, f, fs)).mean() for f in fbs])
    far, near = np.argmax(rng), np.argmin(rng)
    assert rel[far] / rel[near] > 1.5
    np.testing.assert_allclose(rel / rel[near], rng / rng[near], rtol=0.2)


def _doppler(x, f, fs, loop_period):
    z = dtft(x, f, fs)
    return np.angle((z[..., 1:] * np.conj(z[..., :-1])).sum()) / (2 * np.pi * loop_period)


def test_09_ego_motion_doppler():
    c, c0 = case("ego_motion"), case("clean")
    r = c.radar_nominal
    v = c.truth["effects"]["ego_motion"]["speed_mps"]
    assert 0.5 <= v <= 2.0
    p, rng, fb = strongest(c)
    want = -2 * v * (p[0] / rng) * r.center_frequency / C
    got = _doppler(c.capture.adc, fb, r.sample_rate, r.loop_period)
    assert abs(got - want) < 0.01 * abs(want), (got, want)
    assert abs(_doppler(c0.capture.adc, fb, r.sample_rate, r.loop_period)) < 2.0


def test_10_moving_scatterer_range_and_doppler():
    c, c0 = case("moving_scatterer"), case("clean")
    r, p = c.radar_nominal, c.truth["effects"]["moving_scatterer"]
    d = c.capture.adc - c0.capture.adc
    pos = np.array(p["position_m"]) - r.position
    rng = np.linalg.norm(pos)
    assert abs(np.argmax(profile(d, 8)) / 8 - rng / r.range_resolution) < 0.5
    vr = np.array(p["velocity_mps"]) @ pos / rng
    got = _doppler(d, 2 * rng * r.slope / C, r.sample_rate, r.loop_period)
    assert abs(got - 2 * vr * r.center_frequency / C) < 0.01 * abs(2 * vr * r.center_frequency / C)


def test_11_adc_clipping_bounds_iq():
    c, c0 = case("adc_clipping"), case("clean")
    level = c.truth["derived"]["clip_level_counts"]
    frac = c.truth["effects"]["adc_clipping"]["fraction"]
    x = c.capture.adc
    iq = np.abs(np.concatenate([x.real.ravel(), x.imag.ravel()]))
    assert iq.max() <= level * (1 + 1e-6)
    at_rail = np.mean(iq >= level * (1 - 1e-6))
    assert 0.01 <= at_rail <= 0.05 and abs(at_rail - frac) < 0.002
    assert np.abs(c0.capture.adc.real).max() > 1.1 * level


def test_12_scene_effects_at_their_geometry():
    c0 = case("clean")
    r = c0.radar_nominal
    miss = case("missing_scatterer")
    pos = np.array(miss.truth["effects"]["missing_scatterer"]["position_m"]) - r.position
    d = miss.capture.adc - c0.capture.adc
    assert abs(np.argmax(profile(d, 8)) / 8 - np.linalg.norm(pos) / r.range_resolution) < 0.5
    ghost = case("multipath_ghost")
    g = ghost.truth["effects"]["multipath_ghost"]
    assert g["surface"] == "floor" and g["image_m"][2] < 0
    img = np.linalg.norm(np.array(g["image_m"]) - r.position)
    d = ghost.capture.adc - c0.capture.adc
    assert abs(np.argmax(profile(d, 8)) / 8 - img / r.range_resolution) < 0.5
    pose = case("pose_offset")
    off = pose.truth["effects"]["pose_offset"]
    assert 0.01 <= np.linalg.norm(off["position_offset_m"]) <= 0.03
    assert abs(off["yaw_offset_deg"]) == 0.5
    p, rng, fb = strongest(pose)
    shift = np.linalg.norm(p - np.array(off["position_offset_m"])) - rng
    grid = fb + np.linspace(-30e3, 30e3, 1201)
    peak = [grid[np.argmax([np.abs(dtft(x, f, r.sample_rate)).sum() for f in grid])]
            for x in (pose.capture.adc, c0.capture.adc)]
    assert abs((peak[0] - peak[1]) - 2 * shift * r.slope / C) < 1.5e3


def test_13_channel_gain_delay_and_frequency_offset():
    c0 = case("clean")
    r = c0.radar_nominal
    _, _, fb = strongest(c0)
    ref = dtft(c0.capture.adc, fb, r.sample_rate).mean(-1)
    c = case("channel_gain")
    ratio = dtft(c.capture.adc, fb, r.sample_rate).mean(-1) / ref
    np.testing.assert_allclose(ratio, fx.gain_array(c.truth["effects"]["channel_gain"]),
                               rtol=0.01)
    c = case("delay_offset")
    ratio = dtft(c.capture.adc, fb, r.sample_rate).mean(-1) / ref
    dtau = fx.delay_array(c.truth["effects"]["delay_offset"])
    assert np.abs(dtau).max() > 10e-12
    np.testing.assert_allclose(np.angle(ratio * np.exp(-2j * np.pi * r.center_frequency * dtau)),
                               0, atol=0.02)
    c = case("frequency_offset")
    (df,) = c.truth["effects"]["frequency_offset"]["rx_chip_hz"]
    grid = fb + np.linspace(-15e3, 15e3, 601)
    peak = [grid[np.argmax([np.abs(dtft(x, f, r.sample_rate)).sum() for f in grid])]
            for x in (c.capture.adc, c0.capture.adc)]
    assert abs(peak[0] - peak[1] - df) < 300


def test_14_outside_effects():
    c0 = case("clean")
    c = case("outside:interference")
    hits = c.truth["derived"]["interference_hit_chirps"]
    energy = (np.abs(c.capture.frames - c0.capture.frames) ** 2).sum(axis=(2, 4))   # [F, T, L]
    mask = np.zeros(energy.shape, bool)
    mask[tuple(np.array(hits).T)] = True
    assert 0 < mask.sum() < mask.size
    assert energy[~mask].max() < 1e-6 * energy[mask].min()
    c = case("outside:tx_droop")
    r, p = c.radar_nominal, c.truth["effects"]["outside:tx_droop"]
    _, _, fb = strongest(c)
    ratio = 20 * np.log10(np.abs(dtft(c.capture.adc, fb, r.sample_rate)).mean(1)
                          / np.abs(dtft(c0.capture.adc, fb, r.sample_rate)).mean(1))   # [T, L]
    t = r.chirp_start_times() - r.chirp_start_times().min()
    tau = p["time_constant_s"]
    want = -np.array(p["droop_db"])[:, None] * (1 - np.exp(-t / tau)) / (1 - np.exp(-t.max() / tau))
    np.testing.assert_allclose(ratio, want, atol=0.05)
    assert np.all(np.diff(ratio, axis=1) < 0.02) and ratio[:, -1].max() < -0.4


def test_15_phase_noise_and_noise_floor():
    c0 = case("clean")
    d = case("phase_noise").capture.adc - c0.capture.adc
    assert np.abs(d).std() > 1.0
    corr = np.abs(np.vdot(d[:, 0], d[:, 1])) / np.linalg.norm(d[:, 0]) / np.linalg.norm(d[:, 1])
    assert corr > 0.5                                   # one LO for every receiver
    assert np.abs(d[:, :, 0] - d[:, :, 1]).std() > 0.5 * np.abs(d).std()   # new draw per chirp
    c = case("noise_floor")
    d = c.capture.adc - c0.capture.adc
    spec = (np.abs(np.fft.fft(d, axis=-1)) ** 2).mean(axis=(0, 2))          # [R, N]
    assert np.all(spec[:, 1:3].mean(1) > 3 * spec[:, 40:80].mean(1))
    level = spec[:, 40:80].mean(1)
    extra = np.array(c.truth["effects"]["noise_floor"]["rx_extra_white_db"])
    assert np.all(np.argsort(level) == np.argsort(extra))


def test_16_coloradar_round_trip(tmp_path):
    c = und.make_case(("channel_gain", "dc_offset"), radar="awr1843", num_frames=2)
    root = und.write_coloradar_run(c, tmp_path / "run")
    doc = json.loads((root / "truth.json").read_text())
    assert doc["effects"] == ["channel_gain", "dc_offset"] and doc["sensor"] == "single_chip"
    for f in range(2):
        back = read_coloradar_run(root, f, sensor=doc["sensor"])
        d = back.adc - c.capture.frames[f]
        assert np.abs(d.real).max() <= 0.5 + 1e-3 and np.abs(d.imag).max() <= 0.5 + 1e-3
        assert back.metadata["frame_period"] == pytest.approx(und.FRAME_PERIOD_S)
        for key in ("start_frequency", "slope", "sample_rate", "num_samples", "num_chirps",
                    "idle_time", "adc_start_time", "ramp_end_time", "tdm_order"):
            assert getattr(back.radar, key) == getattr(c.radar_nominal, key), key
        np.testing.assert_allclose(back.radar.tx_positions, c.radar_nominal.tx_positions,
                                   atol=1e-12)
        np.testing.assert_allclose(back.radar.rx_positions, c.radar_nominal.rx_positions,
                                   atol=1e-12)
    for name, mesh in c.meshes.items():
        m = trimesh.load(root / doc["meshes"][name], process=False)
        np.testing.assert_allclose(m.vertices, mesh.vertices, atol=1e-6)
    assert doc["materials"] == c.materials and set(c.materials) == set(c.meshes)
    pose = (root / "calib" / "transforms" / "base_to_single_chip.txt").read_text().split()
    np.testing.assert_allclose([float(v) for v in pose], [0, 0, 1, 0, 0, 0, 1])
    with pytest.raises(FileExistsError):
        und.write_coloradar_run(c, root)


def test_17_same_seed_same_bytes():
    kind = ("phase_noise", "noise_floor")
    a = und.make_case(kind, seed=3, radar="awr1843", num_chirps=2, num_samples=64)
    b = und.make_case(kind, seed=3, radar="awr1843", num_chirps=2, num_samples=64)
    other = und.make_case(kind, seed=4, radar="awr1843", num_chirps=2, num_samples=64)
    assert a.capture.frames.tobytes() == b.capture.frames.tobytes()
    assert json.dumps(a.truth, sort_keys=True) == json.dumps(b.truth, sort_keys=True)
    assert a.capture.frames.tobytes() != other.capture.frames.tobytes()


@pytest.mark.parametrize("kwargs, words", [
    (dict(kind="bogus"), "unknown kind"),
    (dict(kind=("dc_offset", "dc_offset")), "twice"),
    (dict(kind=("dc_offset", 3)), "kind must be"),
    (dict(kind="clean", snr_db=float("nan")), "snr_db"),
    (dict(kind="clean", snr_db=200), "snr_db"),
    (dict(kind="clean", snr_db="high"), "snr_db"),
    (dict(kind="clean", radar="xwr9999"), "radar must be"),
    (dict(kind="clean", num_chirps=0), "num_chirps"),
    (dict(kind="clean", num_samples=4096), "ADC window"),
    (dict(kind="clean", seed=-1), "seed"),
])
def test_18_bad_input_raises(kwargs, words):
    kind = kwargs.pop("kind")
    with pytest.raises(InputValueError, match=words):
        und.make_case(kind, **kwargs)
    with pytest.raises(InputValueError, match="subset"):
        und.suite("medium")


def test_19_mesh_holds_the_corners_and_approximates_the_clutter():
    c = case("clean")
    for k, corner in enumerate(c.truth["corners"]):
        m = c.meshes[f"corner_{k}"]
        centre, axis = np.array(corner["centre_m"]), np.array(corner["axis"])
        assert c.materials[f"corner_{k}"] == "metal"
        assert np.all(m.face_normals @ axis > 0.3)
        if corner["kind"] == "trihedral":
            assert len(m.faces) == 3
            assert np.allclose(m.vertices[m.faces[:, 0]], centre)
            n = m.face_normals
            np.testing.assert_allclose(n @ n.T, np.eye(3), atol=1e-9)
            np.testing.assert_allclose(m.area_faces, corner["size_m"] ** 2 / 2)
        else:
            assert len(m.faces) == 4
            assert abs(np.dot(*m.face_normals[[0, 2]])) < 1e-9
    rects = [r for r in und._Context(c.radar_nominal, 0, 1, None).scene.rects]
    pts = np.array(c.truth["clutter"]["positions_m"])
    assert len(pts) > 1000
    dist = np.full(len(pts), np.inf)
    for r in rects:
        rel = pts - r.origin
        a = rel @ r.edge_u / (r.edge_u @ r.edge_u)
        b = rel @ r.edge_v / (r.edge_v @ r.edge_v)
        on = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        dist = np.where(on, np.minimum(dist, np.abs(rel @ r.normal)), dist)
    assert np.all(dist <= 0.0201) and np.mean(dist > 0.005) > 0.5


def test_20_fast_suite():
    t0 = time.perf_counter()
    cases = und.suite("fast")
    elapsed = time.perf_counter() - t0
    assert elapsed < 10.0, elapsed
    names = [c.name for c in cases]
    assert names[0] == "clean" and len(set(names)) == len(names) >= 6
    assert {"outside:interference", "outside:tx_droop", "pose_offset"} <= set(names)
    clean = cases[0].capture.frames
    for c in cases[1:]:
        assert c.effects and c.name == "+".join(c.effects)
        assert np.abs(c.capture.frames - clean).max() > und.NOISE_STD_COUNTS, c.name
        assert "effects" not in c.capture.metadata and c.name not in str(c.capture.metadata)
    full = und.suite_kinds("full")
    library = [k for k in full if isinstance(k, str) and k in und.LIBRARY_EFFECTS]
    assert len(library) == 15 and sum(isinstance(k, tuple) for k in full) >= 8


def test_21_cascade_radar_is_coloradars(measured_dir):
    calib = measured_dir / "coloradar_calib"
    if not calib.is_dir():
        pytest.skip("coloradar_calib absent")
    from sionna_mmir.radar.config import RadarConfig
    with pytest.warns(UserWarning):
        from sionna_mmir.captures import read_coloradar_config

        ref = read_coloradar_config(calib, "cascade")
    ours = und.coloradar_cascade()
    for key in ("start_frequency", "slope", "sample_rate", "num_samples", "num_chirps",
                "idle_time", "adc_start_time", "ramp_end_time", "tdm_order"):
        assert getattr(ours, key) == pytest.approx(getattr(ref, key), rel=1e-9), key
    np.testing.assert_allclose(ours.tx_positions, ref.tx_positions, atol=1e-12)
    np.testing.assert_allclose(ours.rx_positions, ref.rx_positions, atol=1e-12)


def test_22_static_and_per_chirp_rendering_agree():
    c = case("clean")
    ctx = und._Context(c.radar_nominal, 0, 1, 300)
    groups = [ctx.scene.clutter, ctx.scene.corner_paths(ctx.lam, ctx.radar_pos)]
    groups += ctx.scene.mirror_paths(c.radar_nominal.center_frequency)
    static = adc.render(c.radar_nominal, groups, adc.Motion(ctx.radar_pos, np.eye(3)), ctx.t,
                        ctx.chirp_times)
    chirpwise = adc.render(c.radar_nominal, groups,
                           adc.Motion(ctx.radar_pos, np.eye(3), np.zeros(3)), ctx.t,
                           ctx.chirp_times)
    np.testing.assert_allclose(chirpwise, static, atol=1e-5 * np.abs(static).max())


def test_23_waveform_variant_puts_the_corners_at_their_range(tmp_path):
    """Another waveform of the same radar (slope, sample rate, samples): the
    strongest corner at its range under the new slope, the run folder's
    waveform read back as written; waveforms that cannot see the room are
    refused."""
    r = und.waveform_variant("awr1843", slope=6e13, sample_rate=5e6, num_samples=256)
    nominal = und.waveform_variant("awr1843")
    assert (r.slope, r.sample_rate, r.num_samples) == (6e13, 5e6, 256)
    assert r.num_tx == nominal.num_tx and r.start_frequency == nominal.start_frequency
    assert r.ramp_end_time >= r.adc_start_time + 256 / 5e6
    c = und.make_case("missing_scatterer", radar=r)
    c0 = und.make_case("clean", radar=r)
    _, rng, _ = strongest(c0)
    assert abs(np.argmax(profile(c0.capture.adc, 8)) / 8 - rng / r.range_resolution) < 0.5
    pos = np.array(c.truth["effects"]["missing_scatterer"]["position_m"]) - r.position
    d = c.capture.adc - c0.capture.adc
    assert abs(np.argmax(profile(d, 8)) / 8 - np.linalg.norm(pos) / r.range_resolution) < 0.5
    root = und.write_coloradar_run(c0, tmp_path / "run")
    back = read_coloradar_run(root, 0, sensor="single_chip")
    for key in ("slope", "sample_rate", "num_samples", "ramp_end_time"):
        assert getattr(back.radar, key) == getattr(r, key), key
    for kw, words in ((dict(slope=4e14), "maximum range"), (dict(sample_rate=1e6), "maximum range"),
                      (dict(num_samples=0), "num_samples"), (dict(slope=-1e13), "slope")):
        with pytest.raises(InputValueError, match=words):
            und.waveform_variant("cascade", **kw)


def test_24_room_scale_makes_a_hall():
    """A room of scale 2.5 (a 25 m hall, a waveform that reaches it): the
    walls 2.5 times as far as the nominal room's (same seed), the corners at
    5-20 m with edges sqrt(2.5) times the room's draws, the strongest corner
    at its range in the capture; the nominal scale makes the same bytes as
    the default; the nominal waveform and scales outside [1, 4] are refused."""
    r = und.waveform_variant("awr1843", slope=4e13)
    room = und.make_case("clean", seed=2, radar=r)
    hall = und.make_case("clean", seed=2, radar=r, room_scale=2.5)
    same = und.make_case("clean", seed=2, radar=r, room_scale=1.0)
    assert same.capture.frames.tobytes() == room.capture.frames.tobytes()
    b0, b1 = room.truth["room"], hall.truth["room"]
    for key in ("x_far", "y_left", "y_right"):
        assert b1[key] == pytest.approx(2.5 * b0[key])
    assert b1["height"] == b0["height"]
    pos = np.asarray(r.position)
    for c in hall.truth["corners"]:
        assert 5.0 <= np.linalg.norm(np.asarray(c["centre_m"]) - pos) <= 20.0
        lo, hi = (0.06, 0.12) if c["kind"] == "trihedral" else (0.05, 0.08)
        assert np.sqrt(2.5) * lo <= c["size_m"] <= np.sqrt(2.5) * hi
    _, rng, _ = strongest(hall)
    assert rng > 5.0
    assert abs(np.argmax(profile(hall.capture.adc, 8)) / 8 - rng / r.range_resolution) < 0.5
    with pytest.raises(InputValueError, match="maximum range"):
        und.make_case("clean", radar="awr1843", room_scale=2.5)
    for bad in (0.5, 5.0, float("nan"), "big", True):
        with pytest.raises(InputValueError, match="room_scale"):
            und.make_case("clean", radar=r, room_scale=bad)
