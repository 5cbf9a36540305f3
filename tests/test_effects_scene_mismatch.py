"""Scene mismatch in the effects model: the per-object basis, its scene-side effects,
chirp averaging and screening.

Truths here are closed forms: point targets synthesised with exact per-pair
delays (``synthesize_adc``) at known gains and positions, so a planted
per-object gain, range offset or radar translation is known exactly.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import highpass_noise

from sionna_mmir.effects import EffectContext, EffectModel
from sionna_mmir.effects.library import candidate_effects
from sionna_mmir.effects.library.scene_mismatch import (ObjectDelay, ObjectGain, ObjectPattern,
                                                        PoseOffset)
from sionna_mmir.effects.scene_basis import SceneBasis
from sionna_mmir.fmcw.synthesize import synthesize_adc
from sionna_mmir.radar.config import SPEED_OF_LIGHT, RadarConfig
from sionna_mmir.residual.screening import screen

TARGETS = np.array([[3.0, 0.8, 0.1], [5.0, -1.2, -0.2], [4.2, 0.1, 0.3]])   # radar frame [m]


def _radar(chirps=4):
    return RadarConfig.awr1843(num_chirps=chirps, num_samples=128)


def _adc(radar, points, gains, shift=np.zeros(3)):
    """Exact per-pair ADC of point targets seen from elements moved by ``shift``."""
    tx, rx = radar.tx_positions + shift, radar.rx_positions + shift
    out = []
    for p, g in zip(points, gains):
        tau = (np.linalg.norm(p - tx, axis=1)[:, None] + np.linalg.norm(p - rx, axis=1)[None])
        tau = tau[..., None] / SPEED_OF_LIGHT
        a = np.full(tau.shape, g / np.linalg.norm(p) ** 2, complex)
        out.append(synthesize_adc(radar, a, tau).astype(np.complex128))
    return np.stack(out)


def _basis(radar, adc, points):
    centre = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
    d = points - centre
    dist = np.linalg.norm(d, axis=1)
    e = np.sum(np.abs(adc) ** 2, axis=(1, 2, 3, 4))
    return SceneBasis(names=[f"p{i}" for i in range(len(points))], adc=adc,
                      directions=d / dist[:, None], ranges=dist,
                      offsets_tx=radar.tx_positions - centre,
                      offsets_rx=radar.rx_positions - centre, rotation=np.eye(3),
                      shares=e / e.sum())


def _noise(shape, std, seed=0):
    rng = np.random.default_rng(seed)
    return std * (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / np.sqrt(2)


def _model(radar, measured, basis):
    ctx = EffectContext(radar, basis=basis)
    m = EffectModel(ctx, measured[None])
    m.fit(trainable=[], maxiter=50)
    return m


def _resid_db(m):
    r = m.residual()
    return 10 * np.log10(np.sum(np.abs(r) ** 2) / np.sum(np.abs(m.y * m.scale) ** 2))


def test_01_object_gain_recovers_planted_gains():
    radar = _radar()
    B = _adc(radar, TARGETS, np.ones(3))
    true = np.array([1.0, 0.4 * np.exp(1j), 2.0 * np.exp(-2j)])
    y = np.tensordot(true, B, axes=1) + _noise(B.shape[1:], 1e-4)
    m = _model(radar, y, _basis(radar, B, TARGETS))
    assert _resid_db(m) > -6
    m.add(ObjectGain())
    m.fit(maxiter=200)
    g = m.components[0].values["gain"]
    rel = np.exp(g[:, 0] + 1j * g[:, 1])
    rel = rel / rel[0]
    np.testing.assert_allclose(rel, true / true[0], rtol=1e-3, atol=1e-3)
    assert _resid_db(m) < -35


def test_02_object_delay_recovers_range_offsets():
    radar = _radar()
    B = _adc(radar, TARGETS, np.ones(3))
    shifted = TARGETS.copy()
    shifted[1] *= (np.linalg.norm(TARGETS[1]) + 0.012) / np.linalg.norm(TARGETS[1])
    y = _adc(radar, shifted, np.ones(3)).sum(axis=0)
    m = _model(radar, y, _basis(radar, B, TARGETS))
    m.add(ObjectGain())
    m.add(ObjectDelay())
    m.fit(maxiter=300)
    dr_ = m.components[1].values["range"]
    assert abs(dr_[1] - 0.012) < 1.5e-3 and abs(dr_[0]) < 1.5e-3 and abs(dr_[2]) < 1.5e-3


def test_03_pose_offset_recovers_a_translation_and_the_residual_vanishes():
    radar = RadarConfig.mmwcas(num_chirps=1)
    B = _adc(radar, TARGETS, np.ones(3))
    shift = np.array([0.006, -0.004, 0.002])
    y = _adc(radar, TARGETS, np.ones(3), shift=shift).sum(axis=0)
    m = _model(radar, y, _basis(radar, B, TARGETS))
    m.add(ObjectGain())
    m.fit(maxiter=200)
    before = _resid_db(m)
    m.add(PoseOffset())
    m.fit(maxiter=400)
    t = m.components[1].values["translation"]
    assert before > -25
    assert _resid_db(m) < -35
    # the range components along the targets' directions are pinned down well
    u = (TARGETS / np.linalg.norm(TARGETS, axis=1)[:, None]) @ (t - shift)
    assert np.max(np.abs(u)) < 5e-4


def test_04_object_pattern_takes_the_strongest_objects_of_the_current_model():
    radar = _radar()
    B = _adc(radar, TARGETS, np.ones(3))
    y = np.tensordot([0.01, 1.0, 0.01], B, axes=1)
    m = _model(radar, y, _basis(radar, B, TARGETS))
    m.add(ObjectGain())
    m.fit(maxiter=200)
    comp = m.add(ObjectPattern(max_objects=1))
    assert comp.effect.objects(m.ctx) == [1]
    assert set(comp.specs) == {"tx1", "rx1"}


def test_05_chirp_averaged_model_keeps_values_and_normalisation():
    radar = _radar(chirps=8)
    B = _adc(radar, TARGETS, np.ones(3))
    true = np.array([1.0, 0.5, 0.3j])
    y = np.tensordot(true, B, axes=1) + _noise(B.shape[1:], 3e-4)
    m = _model(radar, y, _basis(radar, B, TARGETS))
    avg = m.chirp_averaged()
    assert avg.ctx.shape[3] == 1 and avg.scale == m.scale and avg.base_gain == m.base_gain
    avg.add(ObjectGain())
    avg.fit(maxiter=200)
    full = m.copy()
    full.add(ObjectGain())
    full.fit(maxiter=200)
    np.testing.assert_allclose(avg.components[0].values["gain"],
                               full.components[0].values["gain"], atol=2e-3)
    moving = m.copy()
    moving.add(candidate_effects("phase_noise")[0])
    with pytest.raises(Exception, match="chirp"):
        moving.chirp_averaged()


def test_06_screening_rules_out_slow_time_effects_on_a_static_capture_only():
    radar = _radar(chirps=8)
    B = _adc(radar, TARGETS, np.ones(3)).sum(axis=0)
    static = B + _noise(B.shape, 1e-4)
    cands = candidate_effects("ego_motion,phase_noise,noise_floor,adc_clipping,channel_gain")
    out = screen(static[None], 1.0, cands)
    assert set(out) == {"ego_motion", "phase_noise", "noise_floor", "adc_clipping"}
    # radar moving at 1 m/s: chirp-to-chirp phase change at the targets' ranges
    moved = dataclasses.replace(radar)
    rate = 2 * 1.0 / SPEED_OF_LIGHT
    a, tau, rho = [], [], []
    for p in TARGETS:
        d = (np.linalg.norm(p - radar.tx_positions, axis=1)[:, None]
             + np.linalg.norm(p - radar.rx_positions, axis=1)[None])[..., None]
        tau.append(d / SPEED_OF_LIGHT)
        rho.append(np.full(d.shape, rate))
        a.append(np.ones(d.shape, complex))
    y = synthesize_adc(moved, np.concatenate(a, -1), np.concatenate(tau, -1),
                       np.concatenate(rho, -1)) + _noise(B.shape, 1e-4)
    out = screen(y[None], 1.0, cands)
    assert "ego_motion" not in out and "phase_noise" not in out
    top = 0.5 * max(np.abs(y.real).max(), np.abs(y.imag).max())   # an ADC clips I and Q
    clipped = np.clip(y.real, -top, top) + 1j * np.clip(y.imag, -top, top)
    assert "adc_clipping" not in screen(clipped[None], 1.0, cands)


def test_07_object_shift_recovers_a_lateral_offset_that_channel_gains_cannot():
    """One of three targets moved 2 cm sideways (a 0.5 rad phase ramp across
    the cascade's aperture, for that object only): the per-object shift
    finds it."""
    from sionna_mmir.effects.library.scene_mismatch import ObjectShift

    radar = RadarConfig.mmwcas(num_chirps=1)
    B = _adc(radar, TARGETS, np.ones(3))
    moved = TARGETS.copy()
    moved[1] += [0.0, 0.02, 0.0]
    y = _adc(radar, moved, np.ones(3)).sum(axis=0)
    m = _model(radar, y, _basis(radar, B, TARGETS))
    m.add(ObjectGain())
    m.fit(maxiter=200)
    before = _resid_db(m)
    m.add(ObjectShift())
    m.fit(maxiter=400)
    s = m.components[1].values["shift"]
    assert before > -30 and _resid_db(m) < before - 20, (before, _resid_db(m))
    np.testing.assert_allclose(s[1], [0.0, 0.02, 0.0], atol=1e-3)
    assert np.abs(s[[0, 2]]).max() < 1e-3


def test_07b_a_pattern_fitted_on_one_object_predicts_the_next_only_when_it_is_the_sensors():
    """A held-out object (:func:`~sionna_mmir.residual.object_transfer.held_out_object_gain`):
    with a per-channel gain planted on every point, the strongest point's
    fitted pattern lowers the next point's NLL by far more than the gain's
    14 parameters cost, and by nearly what that point's own pattern does;
    with the same gain on the strongest point alone (a scene mismatch of
    that object) it raises it.  With one object there is nothing to ask."""
    from sionna_mmir.residual.object_transfer import held_out_object_gain
    from sionna_mmir.residual.ranking import BIC, penalty_per_param

    radar = _radar(chirps=1)
    B = _adc(radar, TARGETS, np.array([3.0, 1.0, 1.0]))
    rng = np.random.default_rng(7)
    gt, gr = (np.exp(rng.normal(0, 0.12, n) + 1j * rng.uniform(-0.5, 0.5, n)) for n in (3, 4))
    g = (gt[:, None] * gr[None, :])[:, :, None, None]
    std = 0.02 * np.sqrt(np.mean(np.abs(B[1]) ** 2))           # the weak points 34 dB over it
    cost = penalty_per_param(BIC, B[0].size) * 14
    noise = _noise(B.shape[1:], std, 1)
    common = _model(radar, (B * g).sum(axis=0) + noise, _basis(radar, B, TARGETS))
    own = _model(radar, B[0] * g + B[1] + B[2] + noise, _basis(radar, B, TARGETS))
    shared, alone = held_out_object_gain(common, ObjectPattern())
    assert shared > 10 * cost and shared > 0.95 * alone
    shared, alone = held_out_object_gain(own, ObjectPattern())
    assert shared < 0 <= alone
    single = _model(radar, B[0] * g + noise, _basis(radar, B[:1], TARGETS[:1]))
    assert held_out_object_gain(single, ObjectPattern()) == (-np.inf, 0.0)   # no object to ask


def test_08_mesh_planes_are_the_large_flat_objects_in_the_radar_frame():
    """A floor, a wall, a small plate and a trihedral seen from a radar 1 m up,
    yawed 30 deg: the floor and the wall come back as planes in the radar
    frame (hand-rotated), normals towards the radar; the plate (0.09 m^2) and
    the trihedral (not flat) do not."""
    from types import SimpleNamespace

    from sionna_mmir.effects.scene_basis import mesh_planes

    def quad(corners):
        return SimpleNamespace(vertex_positions=np.array(corners, float),
                               faces=np.array([[0, 1, 2], [0, 2, 3]]))

    tri = SimpleNamespace(vertex_positions=np.array([[3, 0, 1], [3.2, 0, 1], [3, 0.2, 1],
                                                     [3, 0, 1.2]], float),
                          faces=np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3]]))
    objects = {"floor": quad([[0, -2, 0], [4, -2, 0], [4, 2, 0], [0, 2, 0]]),
               "wall": quad([[0, 2.5, 0], [4, 2.5, 0], [4, 2.5, 3], [0, 2.5, 3]]),
               "plate": quad([[2, 0, 1], [2, 0.3, 1], [2, 0.3, 1.3], [2, 0, 1.3]]),
               "corner": tri}
    yaw = np.radians(30.0)
    radar = RadarConfig.awr1843(position=np.array([0.0, 0.0, 1.0]),
                                orientation=np.array([yaw, 0.0, 0.0]))
    planes = {name: (q, n) for name, q, n in mesh_planes(objects, radar)}
    assert sorted(planes) == ["floor", "wall"]
    q, n = planes["floor"]
    assert n == pytest.approx([0, 0, 1], abs=1e-9) and q[2] == pytest.approx(-1.0, abs=1e-9)
    q, n = planes["wall"]
    # the wall's normal -y (scene) seen in a frame yawed by +30 deg: -(sin 30, cos 30, 0)
    assert n == pytest.approx([-np.sin(yaw), -np.cos(yaw), 0], abs=1e-9)
    assert np.dot(q, n) == pytest.approx(-2.5, abs=1e-9)       # 2.5 m from the radar


def test_08b_a_point_seen_through_the_ground_is_refused():
    """The same floor and wall: only the floor is ground (the wall faces
    sideways), its two triangles 4 x 4 m centred 2 m ahead, 1 m below the
    yawed radar. A point fitted 1 m under the floor, 2 m ahead, lies
    behind it (``behind_ground``) and a missing scatterer there gets an
    infinite floor; the same point above the floor, on the floor, and a
    point under the floor's plane whose line of sight passes beside or
    beyond the floor do not (hand geometry)."""
    from types import SimpleNamespace

    from sionna_mmir.effects import EffectContext
    from sionna_mmir.effects.library.scatterer import MissingScatterer
    from sionna_mmir.effects.scene_basis import behind_ground, mesh_grounds

    def quad(corners):
        return SimpleNamespace(vertex_positions=np.array(corners, float),
                               faces=np.array([[0, 1, 2], [0, 2, 3]]))

    objects = {"floor": quad([[0, -2, 0], [4, -2, 0], [4, 2, 0], [0, 2, 0]]),
               "wall": quad([[0, 2.5, 0], [4, 2.5, 0], [4, 2.5, 3], [0, 2.5, 3]])}
    yaw = np.radians(30.0)
    radar = RadarConfig.awr1843(position=np.array([0.0, 0.0, 1.0]),
                                orientation=np.array([yaw, 0.0, 0.0]))
    grounds = mesh_grounds(objects, radar)
    assert [g[0] for g in grounds] == ["floor"]
    _, c, n, axes, tris = grounds[0]
    to_radar = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0],
                         [0, 0, 1]]).T                    # scene -> radar frame, by hand
    assert c == pytest.approx(to_radar @ [2.0, 0.0, -1.0], abs=1e-9)
    assert tris.shape == (2, 3, 2) and np.abs(axes @ n).max() < 1e-12

    def at(x, y, z):                                  # a scene point in the radar frame
        return to_radar @ np.array([x, y, z - 1.0])

    assert behind_ground(at(2.0, 0.5, -1.0), grounds)
    assert not behind_ground(at(2.0, 0.5, 0.5), grounds)
    assert not behind_ground(at(2.0, 0.5, 0.0), grounds)        # on the floor
    assert not behind_ground(at(2.0, 0.5, -0.2), grounds)       # within the margin
    assert not behind_ground(at(9.0, 0.0, -0.5), grounds)       # crosses z = 0 at x = 6 m
    assert behind_ground(at(2.0, 3.0, -1.0), grounds)           # crosses it at (1, 1.5)
    assert not behind_ground(at(2.0, 5.0, -1.0), grounds)       # at (1, 2.5): beside it
    assert not behind_ground(at(8.4, 0.0, -1.0), grounds)       # at (4.2, 0): beyond its edge

    basis = SimpleNamespace(grounds=grounds)
    model = SimpleNamespace(ctx=EffectContext(radar, basis=basis))
    eff = MissingScatterer()

    def floor_at(p):
        r = np.linalg.norm(p)
        az, el = np.degrees(np.arctan2(p[1], p[0])), np.degrees(np.arcsin(p[2] / r))
        return eff.fitted_gain_floor(model, {"range": [r], "azimuth": [az], "elevation": [el],
                                             "amp": [1.0, 0.0]})

    assert floor_at(at(2.0, 0.5, -1.0)) == float("inf")
    assert floor_at(at(2.0, 0.5, 0.5)) == eff.min_gain_per_sample
    basis.grounds = []                                # a scene without ground refuses nothing
    assert floor_at(at(2.0, 0.5, -1.0)) == eff.min_gain_per_sample


@pytest.mark.parametrize("effect,steps,start", [
    ("PoseOffset", {"translation": 1e-4, "rotation": 1e-4},
     {"translation": [0.003, -0.002, 0.001], "rotation": [0.001, -0.002, 0.001]}),
    ("ObjectShift", {"shift": 1e-4}, {"shift": [[0.002, 0.01, 0.0], [0.0, 0.004, 0.001],
                                                [0.001, 0.0, -0.002]]}),
    ("ObjectDelay", {"range": 1e-4}, {"range": [0.002, -0.003, 0.001]}),
    ("ObjectGain", {"gain": 1e-3}, {"gain": [[0.1, 0.2], [-0.1, 0.0], [0.05, -0.3]]}),
])
def test_09_pose_and_object_delay_gradients_match_finite_differences(effect, steps, start):
    """The per-pair delay effects (through the basis' pose-delay map and its
    pair means): AD of the NLL against central differences, off the optimum
    (a capture with the targets moved, the model's values elsewhere)."""
    from helpers import check_nll_gradients
    from sionna_mmir.effects.library import scene_mismatch

    radar = RadarConfig.mmwcas(num_chirps=1)
    B = _adc(radar, TARGETS, np.ones(3))
    moved = TARGETS + np.array([[0.0, 0.02, 0.0], [0.004, 0.0, 0.0], [0.0, 0.0, 0.003]])
    y = _adc(radar, moved, np.ones(3)).sum(axis=0) + _noise(B.shape[1:], 1e-3)
    m = _model(radar, y, _basis(radar, B, TARGETS))
    comp = m.add(getattr(scene_mismatch, effect)())
    for key, value in start.items():
        comp.values[key] = np.asarray(value, float).reshape(comp.values[key].shape)
    err = check_nll_gradients(m, 0, steps)
    assert max(err.values()) < 0.02


@pytest.mark.parametrize("shared", [False, True])
def test_09b_object_pattern_gradients_match_finite_differences(shared):
    """Per-object patterns (per-Tx x per-Rx log-amplitude and phase), and the
    strongest object's pattern given to every object as the held-out object
    test evaluates it (:meth:`ObjectPattern.shared`): AD of the NLL against
    central differences, off the optimum (a capture with a planted
    per-channel gain, the patterns elsewhere)."""
    from helpers import check_nll_gradients

    radar = _radar(chirps=1)
    B = _adc(radar, TARGETS, np.array([3.0, 1.0, 1.0]))
    rng = np.random.default_rng(11)
    g = np.exp(rng.normal(0, 0.1, (3, 4)) + 1j * rng.uniform(-0.4, 0.4, (3, 4)))
    y = (B * g[None, :, :, None, None]).sum(axis=0) + _noise(B.shape[1:], 1e-3)
    m = _model(radar, y, _basis(radar, B, TARGETS))
    eff = ObjectPattern(max_objects=1) if shared else ObjectPattern()
    comp = m.add(eff)
    if shared:
        comp.effect, comp.specs, comp.values = eff.shared(comp, m.ctx, [0, 1, 2])
    for key in comp.values:
        comp.values[key] = rng.normal(0, 0.1, comp.values[key].shape)
    err = check_nll_gradients(m, 0, {k: 1e-3 for k in comp.values})
    assert max(err.values()) < 0.02


def _behind_highpass(radar, ratio):
    """``(f_hp, H [3], B)``: a first-order high-pass at the nearest target's
    beat frequency over ``ratio``, its response at each target's beat
    frequency (``scipy.signal.freqs``) and the targets' unit-gain ADC."""
    from scipy import signal

    centre = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
    f_b = 2 * np.linalg.norm(TARGETS - centre, axis=1) * radar.slope / SPEED_OF_LIGHT
    f_hp = f_b.min() / ratio
    _, H = signal.freqs([1.0, 0.0], [1.0, 2 * np.pi * f_hp], worN=2 * np.pi * f_b)
    return f_hp, H, _adc(radar, TARGETS, np.ones(3))


def test_11_if_filter_is_scored_with_the_object_gains_refitted_beside_it():
    """Three targets behind a first-order IF high-pass (corner 1.2 times
    under the nearest one's beat frequency; truth: ``scipy.signal.freqs``
    per path).  The base fit's object gains take each target's attenuation
    and phase; scored as the loop scores it (``_fit_candidate``), the filter
    refits them beside it (``refit_beside``) and gains 20-35 % more per
    sample than held beside them at their fitted values."""
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.residual.ranking import _fit_candidate

    radar = _radar(chirps=4)
    f_hp, H, B = _behind_highpass(radar, 1.2)
    y = np.tensordot(H, B, axes=1) + _noise(B.shape[1:], 1e-3 * np.abs(B).max())
    m = _model(radar, y, _basis(radar, B, TARGETS))
    m.add(ObjectGain())
    m.fit(maxiter=200)
    assert IFFilter.refit_beside == ("object_gain",)
    nll = {}
    for beside in (("object_gain",), ()):
        cand = m.copy()
        eff = IFFilter(highpass_stages=1, transient=False)
        eff.refit_beside = beside
        cand.add(eff)
        _fit_candidate(cand, eff, None, 200)
        nll[beside] = cand.nll()
    base = m.nll()                  # object gains converged: refitting them alone gains ~0
    with_gains, held = base - nll[("object_gain",)], base - nll[()]
    # measured 0.341 / 0.253 (AVX-512 CPU), 0.303 / 0.253 (AVX2: the filter's
    # corner settles in another basin beside the refitted gains)
    assert held > 0 and with_gains > 1.1 * held, (base, nll)


def test_11c_an_if_filter_starts_at_its_noise_notch_where_object_gains_took_its_response(
        monkeypatch):
    """Three targets behind two first-order high-pass stages (corners a fifth
    of the nearest beat frequency) and receiver noise through the same stages
    (truth: ``scipy.signal.freqs`` per path, ``scipy.signal.lfilter`` on the
    noise).  The base fit's object gains take the targets' attenuation and
    phase, so the filter's signal-side response explains nothing more; the
    notch it cuts into the noise at near-DC bins is its signature.  Filtered
    once more, the model would count the attenuation twice: the start is
    judged with the object gains able to take it back (they are refitted
    beside the filter), so the filter starts at the notch, not switched off,
    and its fit finds the planted corners (to 20 %: the notch's shape at 8
    chirps of 12 channels identifies them to about 15 %; 0.82-1.16 of the
    planted corner over noise levels and seeds)."""
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.residual.ranking import _fit_candidate

    radar = _radar(chirps=8)
    f_hp, H, B = _behind_highpass(radar, 5)
    n = highpass_noise(_noise(B.shape[1:], 0.01 * np.abs(B).max()), f_hp, radar.sample_rate, 2)
    y = np.tensordot(H * H, B, axes=1) + n
    m = _model(radar, y, _basis(radar, B, TARGETS))
    m.add(ObjectGain())
    m.fit(maxiter=200)
    off = IFFilter()
    cand = m.copy()
    comp = cand.add(off)
    corners = 10 ** np.r_[comp.values["log_fc"][0], comp.values["log_hp2"]] * 1e3
    assert np.all(corners > 0.3 * f_hp), corners              # the noise start, not off
    _fit_candidate(cand, off, None, 200)
    corners = 10 ** np.r_[comp.values["log_fc"][0], comp.values["log_hp2"]] * 1e3
    assert np.allclose(corners, f_hp, rtol=0.2), (corners, f_hp)
    assert float(comp.values["pre_noise"][0]) > 0.8
    assert (m.nll() - cand.nll()) * np.prod(m.ctx.shape) > 200     # measured 1363
    # judged with the object gains held, the start is the filter switched off
    judged = IFFilter._start_nll
    monkeypatch.setattr(IFFilter, "_start_nll", lambda self, ctx, model, data, st, absorbed:
                        judged(self, ctx, model, data, st, False))
    comp = m.copy().add(IFFilter())
    assert 10 ** comp.values["log_fc"][0] * 1e3 < 0.01 * f_hp


def _delayed_targets(radar, tx_ps, rx_ps):
    """Three targets seen through per-Tx and per-Rx delays [ps] (exact
    per-pair delays plus the planted ones) and thermal noise at -60 dB."""
    B = _adc(radar, TARGETS, np.array([1.0, 0.7, 0.5]))
    d = (np.asarray(tx_ps)[:, None] + np.asarray(rx_ps)[None, :]) * 1e-12
    tx, rx = radar.tx_positions, radar.rx_positions
    y = 0
    for p, g in zip(TARGETS, [1.0, 0.7, 0.5]):
        tau = (np.linalg.norm(p - tx, axis=1)[:, None] + np.linalg.norm(p - rx, axis=1)[None])
        tau = tau / SPEED_OF_LIGHT + d
        a = np.full(tau.shape, g / np.linalg.norm(p) ** 2, complex)
        y = y + synthesize_adc(radar, a[..., None], tau[..., None]).astype(np.complex128)
    return B, y + _noise(B.shape[1:], 1e-3 * np.abs(B).max())


def _refined(radar, B, y):
    """The model on the targets' basis with the base refinement fitted as
    ``RadarModel.refine`` fits it (per-object gains, then the pose)."""
    from sionna_mmir.effects.library.scene_mismatch import BASE_REFINEMENT

    m = _model(radar, y, _basis(radar, B, TARGETS))
    for cls in BASE_REFINEMENT:
        m.add(cls())
        m.fit(maxiter=200)
    return m


def test_11b_per_channel_delays_are_scored_with_the_base_refinement_refitted_beside_them():
    """Three targets seen through per-Tx and per-Rx delays of several carrier
    cycles (truth: exact per-pair delays plus the planted ones).  The base
    refinement, fitted first, bends gains and pose to the scrambled channel
    phases; scored on held-out channels as the loop scores candidates, delays
    that refit that refinement beside them predict the held-out channels far
    better than delays held beside its bent values (the loop refits it only
    while it is pinned: test 11d)."""
    from sionna_mmir.effects.library.delay_offset import DelayOffset
    from sionna_mmir.effects.library.scene_mismatch import BASE_REFINEMENT_NAMES
    from sionna_mmir.residual.ranking import cv_folds, rank_candidates

    radar = _radar(chirps=2)
    m = _refined(radar, *_delayed_targets(radar, [-45.0, 11.0, -43.0], [-1.0, 6.0, 35.0, 4.0]))
    assert DelayOffset.refit_beside == ()
    folds = cv_folds(m.ctx.shape[:4], 3)
    scores = {}
    for beside in (BASE_REFINEMENT_NAMES, ()):
        eff = DelayOffset()
        eff.refit_beside, eff.channel_phase = beside, False
        (scores[beside],) = rank_candidates(m, [eff], folds)
    new, held = scores[BASE_REFINEMENT_NAMES], scores[()]
    # measured: -48.7 dB held-out energy change and 34 900 nats, against
    # -14.1 dB and 9 900 nats beside the bent refinement
    assert new.energy_change_db < -30.0 and held.energy_change_db > -25.0, (new, held)
    assert new.gain > 2.0 * held.gain > 0, (new, held)


def test_11d_a_pinned_refinement_is_refitted_beside_per_channel_phase_candidates():
    """While the refinement's pose sits on its bounds (it chased per-channel
    delays of several carrier cycles), the ranking refits the refinement
    beside a per-channel phase candidate (``refinement_pinned``,
    ``Effect.channel_phase``) and scores the delays as test 11b's hand-made
    refit; with the pose inside its box, nothing is refitted beside them.
    Truth: exact per-pair delays."""
    from sionna_mmir.effects.library.delay_offset import DelayOffset
    from sionna_mmir.effects.library.scene_mismatch import refinement_pinned
    from sionna_mmir.residual.ranking import cv_folds, rank_candidates

    radar = _radar(chirps=2)
    m = _refined(radar, *_delayed_targets(radar, [-45.0, 11.0, -43.0], [-1.0, 6.0, 35.0, 4.0]))
    assert refinement_pinned(m), [c.values for c in m.components]
    assert DelayOffset.channel_phase and not ObjectPattern.channel_phase
    folds = cv_folds(m.ctx.shape[:4], 3)
    (refitted,) = rank_candidates(m, [DelayOffset()], folds)
    pose = next(c for c in m.components if isinstance(c.effect, PoseOffset))
    pose.values = {k: 0.9 * np.asarray(v) for k, v in pose.values.items()}   # inside its box
    assert not refinement_pinned(m)
    (held,) = rank_candidates(m, [DelayOffset()], folds)
    # measured: -14.9 dB held on two CPUs; refitted beside the pinned refinement
    # (held first, then freed) -43.6 dB on an AVX-512 Xeon of one generation and
    # -23.7 dB on another (where the freed pose's fit stops moves with rounding)
    assert held.energy_change_db > -20.0, held
    assert refitted.energy_change_db < held.energy_change_db - 6.0, (refitted, held)


@pytest.mark.parametrize("pinned", [True, False])
def test_11e_a_phase_adoption_beside_a_pinned_refinement_has_a_second_start(pinned):
    """An adoption whose joint refit beside the freed refinement ends worse
    than its start (forced here by spoiling the nuisance gain after it) is
    fitted again with the refinement held, and adopted when that start
    lowers the residual; with the pose inside its box there is one start
    and the adoption is undone.  Truth: exact per-pair delays."""
    from sionna_mmir.effects.library.delay_offset import DelayOffset
    from sionna_mmir.residual import diagnosis as dg

    radar = _radar(chirps=2)
    m = _refined(radar, *_delayed_targets(radar, [-45.0, 11.0, -43.0], [-1.0, 6.0, 35.0, 4.0]))
    if not pinned:
        pose = next(c for c in m.components if isinstance(c.effect, PoseOffset))
        pose.values = {k: 0.9 * np.asarray(v) for k, v in pose.values.items()}
    real_adopt, starts = dg._adopt, []

    def first_start_lost(model, eff, maxiter, fits, clock=None, hold_refinement=False):
        comp = real_adopt(model, eff, maxiter, fits, clock, hold_refinement=hold_refinement)
        starts.append(hold_refinement)
        if not hold_refinement:
            model.nuisance.values["gain"] = model.nuisance.values["gain"] * 3.0
        return comp

    mp = pytest.MonkeyPatch()
    mp.setattr(dg, "_adopt", first_start_lost)
    try:
        run = dg.DiagnosisRun(m, [DelayOffset()], workers=1)
        first = run.first["residual_energy_db"]
        a = run.step()
    finally:
        mp.undo()
    if pinned:
        assert starts == [False, True] and not run.vetoes
        assert a.name == "delay_offset" and a.after["residual_energy_db"] < first - 10.0, a.after
        assert a.starts == 2
    else:
        assert starts == [False] and a is None
        assert [v["name"] for v in run.vetoes] == ["delay_offset"]


def test_12_a_chirp_invariant_basis_is_kept_per_frame_and_broadcast_once():
    """A static scene's per-object basis is the same in every chirp loop: the
    model keeps it ``[1, T, R, 1, N]`` and spreads the scene-side result to
    ``[F, T, R, C, N]`` once.  Truth: the same model with the basis held at
    full size (the reference twin): the NLL and every gradient agree beside
    a chirp-varying mover; a basis that differs between chirps stays full."""
    import drjit as dr

    from sionna_mmir.effects import ops
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.effects.library.scene_mismatch import PoseOffset

    radar = _radar(chirps=4)
    B = _adc(radar, TARGETS, np.ones(3))
    y = _adc(radar, TARGETS, [1.0, 0.7, 1.3], shift=np.array([0.0, 0.004, 0.0])).sum(axis=0)
    m = _model(radar, y + _noise(y.shape, 1e-3), _basis(radar, B, TARGETS))
    for eff in (ObjectGain(), PoseOffset(), MovingScatterer()):
        m.add(eff)
    m.components[0].values["gain"] = m.components[0].values["gain"] + 0.1
    m.components[1].values["translation"] = np.array([0.001, 0.003, -0.002])
    assert [tuple(b[0].shape) for b in m.basis_t] == [(1, 3, 4, 1, 128)] * 3

    def loss_and_grads(model):
        keys = [(-1, k) for k in model.nuisance.specs] + \
            [(i, k) for i, c in enumerate(model.components) for k in c.specs]
        mask, n = model.mask_tensor(None)
        with ops.single_thread(), model.held():
            tens = model._tensors(grad_keys=set(keys))
            loss = model.loss(tens, mask, n, None)
            dr.backward(loss)
            g = np.concatenate([np.asarray(dr.grad(tens[k]), np.float64).ravel() for k in keys])
            return ops.item(loss), g

    full = m.copy()
    k = full.base_gain / full.scale
    full.basis_t = [ops.tensor(np.broadcast_to(b[None], full.ctx.shape) * k)
                    for b in full.ctx.basis.adc]
    (l0, g0), (l1, g1) = loss_and_grads(full), loss_and_grads(m)
    assert l1 == pytest.approx(l0, rel=1e-6, abs=1e-6)
    assert np.max(np.abs(g1 - g0)) <= 1e-5 * max(np.max(np.abs(g0)), 1e-12)
    assert np.allclose(m.mean_variance_numpy()[0], full.mean_variance_numpy()[0], atol=1e-6)
    varied = B.copy()
    varied[:, :, :, 1] *= 1.01                      # not the same in every chirp
    other = _model(radar, y, _basis(radar, varied, TARGETS))
    assert all(tuple(b[0].shape) == (1, 3, 4, 4, 128) for b in other.basis_t)
