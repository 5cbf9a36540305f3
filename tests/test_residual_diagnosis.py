"""Building blocks of the residual diagnosis: folds, the profiled held-out score,
the per-channel chain response, mean-before-variance ranking, backfitting."""
from __future__ import annotations

import numpy as np
import pytest
from helpers import highpass_noise
from scipy import signal

from sionna_mmir.effects import EffectContext, EffectModel
from sionna_mmir.effects.library.channel_gain import ChannelGain
from sionna_mmir.effects.library.noise_floor import NoiseFloor
from sionna_mmir.effects.library.scatterer import MissingScatterer
from sionna_mmir.errors import ConfigError
from sionna_mmir.fmcw.synthesize import synthesize_adc
from sionna_mmir.radar.config import RadarConfig
from sionna_mmir.residual import cv_folds, diagnose

C = 299_792_458.0


def _clean(radar):
    return synthesize_adc(radar, np.array([1.0, 0.4j]), 2 * np.array([1.8, 3.7]) / C)[None]


def _noise(shape, std, seed):
    rng = np.random.default_rng(seed)
    return std * (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / np.sqrt(2)


def test_01_channel_folds_hold_out_whole_channels_and_keep_every_tx_and_rx():
    shape = (2, 3, 4, 5)                                      # F, T, R, C
    trains = cv_folds(shape, 3, seed=1)
    assert len(trains) == 3
    held = np.zeros(shape[1:3], int)
    for t in trains:
        # a channel is held out in all its frames and chirps, or not at all
        per_ch = t.reshape(2, 3, 4, 5).transpose(1, 2, 0, 3).reshape(3, 4, -1)
        assert np.all(per_ch.all(-1) | ~per_ch.any(-1))
        held += ~per_ch[..., 0]
        assert t.any(axis=(0, 2, 3)).all() and t.any(axis=(0, 1, 3)).all()
    assert np.all(held == 1)                                   # each channel held out once


def test_02_small_arrays_fall_back_to_cells_and_bad_groups_are_refused():
    # 1 Tx x 2 Rx: 2 channels < 2 per fold -> cells
    trains = cv_folds((1, 1, 2, 6), 3, seed=0)
    test = [~t for t in trains]
    assert sum(int(t.sum()) for t in test) == 12
    assert any(t[0, 0, 0].any() and not t[0, 0, 0].all() for t in test)   # split inside a channel
    with pytest.raises(ConfigError, match="too few"):
        cv_folds((1, 1, 2, 6), 3, groups="channel")
    with pytest.raises(ConfigError, match="groups"):
        cv_folds((1, 3, 4, 2), 3, groups="chirps")
    with pytest.raises(ConfigError, match="folds"):
        cv_folds((1, 3, 4, 2), 1)


def test_03_profiled_nll_is_the_closed_form_without_variance_effects():
    radar = RadarConfig.awr1843(num_chirps=2, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    noise = _noise(clean.shape, 0.05, 0)
    m = EffectModel(ctx, clean + noise, clean)
    m.fit(trainable=[])
    cells = np.zeros(ctx.shape[:4], bool)
    cells[:, 1] = True
    r = (m.y - m.mean_variance_numpy()[0])[cells]
    # unitary DFT: residual power is the same in both domains; NLL = log(mean |r|^2) + 1
    assert m.nll_profiled(cells) == pytest.approx(np.log(np.mean(np.abs(r) ** 2)) + 1, abs=1e-4)
    # and never above the NLL with the fitted floor (it minimises over sigma^2)
    assert m.nll_profiled(cells) <= m.nll(cells) + 1e-6


def test_04_profiled_nll_with_a_variance_effect_matches_a_brute_force_minimum():
    radar = RadarConfig.awr1843(num_chirps=2, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    m = EffectModel(ctx, clean + _noise(clean.shape, 0.05, 1), clean)
    comp = m.add(NoiseFloor())
    comp.values["level"] = np.full(radar.num_rx, -4.0)
    m.fit(trainable=[])
    x, v = m.mean_variance_numpy()
    Y = np.fft.fft(m.y, axis=-1, norm="ortho")
    r2 = np.abs(Y - np.fft.fft(x, axis=-1, norm="ortho")) ** 2
    extra = v - np.exp(m.nuisance.values["log_noise"][0])
    grid = np.linspace(-15, 2, 20001)
    brute = min(np.mean(r2 / (np.exp(g) + extra) + np.log(np.exp(g) + extra)) for g in grid[::20])
    assert m.nll_profiled() == pytest.approx(brute, abs=2e-3)
    assert m.nll_profiled() <= brute + 1e-6


def test_05_channel_response_recovers_a_per_channel_gain():
    radar = RadarConfig.awr1843(num_chirps=2, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    m = EffectModel(ctx, clean, clean)
    assert np.allclose(m.channel_response(), 1.0)               # no sensor effect yet
    comp = m.add(ChannelGain())
    T, R = radar.num_tx, radar.num_rx
    rng = np.random.default_rng(2)
    lt, lr = rng.normal(0, 0.2, T), rng.normal(0, 0.2, R)
    pt, pr = rng.uniform(-3, 3, T), rng.uniform(-3, 3, R)
    comp.values = {"tx": np.stack([lt, pt], -1), "rx": np.stack([lr, pr], -1)}  # (Np, rad)
    x = m.mean_variance_numpy()[0]
    gain = m.nuisance.values["gain"]
    pre = m.b * complex(gain[0], gain[1])
    expected = np.sum(np.conj(pre) * x, axis=(0, 3, 4)) / np.sum(np.abs(pre) ** 2, axis=(0, 3, 4))
    h = m.channel_response()[0, :, :, 0, 0]
    assert np.allclose(h, expected, rtol=1e-4)
    # a pure per-channel gain: h is the gain itself, up to the one common factor
    truth = np.exp(lt[:, None] + lr[None] + 1j * (pt[:, None] + pr[None]))
    ratio = h / truth
    assert np.allclose(ratio, ratio[0, 0], rtol=1e-4)


def test_06_scatterer_behind_channel_phases_is_found_at_its_true_angle():
    """A missing scatterer whose channels carry random per-Tx/Rx phases (adopted
    first as a channel gain) is initialised on the referred residual."""
    radar = RadarConfig.awr1843(num_chirps=2, num_samples=64)
    ctx = EffectContext(radar)
    T, R = radar.num_tx, radar.num_rx
    rng = np.random.default_rng(4)
    g = np.exp(1j * (rng.uniform(-np.pi, np.pi, T)[:, None] + rng.uniform(-np.pi, np.pi, R)[None]))
    from helpers import point_targets_adc

    def render(targets):
        return point_targets_adc(radar, targets)

    base_targets = [(1.5, 0.0, 1.0), (3.4, np.radians(-20), 0.5)]
    extra = (2.6, np.radians(25), 0.4)
    clean = render(base_targets)
    meas = render(base_targets + [extra]) * g[None, :, :, None, None] + \
        _noise(clean.shape, 0.01, 5)
    d = diagnose(EffectModel(ctx, meas, clean), [ChannelGain(), MissingScatterer()],
                 max_rounds=3)
    assert d.adopted[:2] == ["channel_gain", "missing_scatterer"], d.adopted
    p = d.adoptions[1].params
    assert abs(p["range_m"] - 2.6) < 0.02 and abs(p["azimuth_deg"] - 25) < 1.0, p


def test_07_variance_effects_are_ranked_only_when_no_mean_effect_helps():
    radar = RadarConfig.awr1843(num_chirps=4, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    T, R = radar.num_tx, radar.num_rx
    rng = np.random.default_rng(6)
    g = np.exp(1j * (rng.uniform(-np.pi, np.pi, T)[:, None] + rng.uniform(-np.pi, np.pi, R)[None]))
    meas = clean * g[None, :, :, None, None] + _noise(clean.shape, 0.01, 7)
    d = diagnose(EffectModel(ctx, meas, clean), [NoiseFloor(), ChannelGain()], max_rounds=1)
    # round 1 scored only the mean candidate (it helped), so the noise floor is unranked
    assert d.adopted == ["channel_gain"]
    assert [c.name for c in d.adoptions[0].candidates] == ["channel_gain"]


def test_08_slot_share_counts_the_transmit_slots_that_gain():
    from sionna_mmir.residual.ranking import slot_share

    shape = (1, 2, 2, 2)                                   # F, T, R, C
    test = np.ones(shape, bool)
    # per held-out cell, in the mask's C order: t0 (r0 c0, r0 c1, r1 c0, r1 c1), t1 (...)
    gains = np.array([5.0, -1.0, 2.0, -3.0, -5.0, 1.0, -2.0, 3.0])
    # transmit slots: (t0, c0) +7, (t0, c1) -4, (t1, c0) -7, (t1, c1) +4 -> two of four;
    # per chirp loop alone (Tx pooled) both would sum to 0
    assert slot_share([gains], [test]) == pytest.approx(0.5)
    assert slot_share([np.abs(gains)], [test]) == pytest.approx(1.0)
    assert slot_share([gains[:2]], [np.zeros((1, 1, 1, 2), bool) | True]) == 1.0   # < 4 slots
    # "most" slots: two standard deviations of a coin toss above one half
    from sionna_mmir.residual.ranking import required_slot_share

    assert required_slot_share(24) == pytest.approx(0.5 + 1 / np.sqrt(24))
    assert 12 / 24 < required_slot_share(24) < 17 / 24
    assert required_slot_share(192) == pytest.approx(0.572, abs=1e-3)
    assert required_slot_share(4) == 1.0


def test_09_a_noise_floor_is_not_adopted_for_a_burst_in_a_few_chirps():
    radar = RadarConfig.awr1843(num_chirps=16, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    meas = clean + _noise(clean.shape, 0.01, 8)
    # a low-frequency burst (interference mixed down near DC): coloured like 1/f noise
    b, a = signal.butter(1, 0.03)
    burst = signal.lfilter(b, a, _noise(clean.shape, 1.0, 9), axis=-1)
    keep = np.zeros(radar.num_chirps, bool)
    keep[[3, 11]] = True
    meas = meas + burst * keep[None, None, None, :, None]  # interference in chirps 3 and 11
    d = diagnose(EffectModel(ctx, meas, clean), [NoiseFloor()], max_rounds=1)
    assert d.adopted == []
    (c,) = d.last_candidates
    assert c.score > 0 and c.slot_share < 0.5              # it helps, but in two chirps only
    # a burst in every chirp loop but in one Tx's transmission of it (TDM: an
    # interferer's sweep crosses ours in some transmit slots) is localised too
    hit = np.arange(radar.num_tx)[:, None] == np.arange(radar.num_chirps)[None, :] % radar.num_tx
    meas = clean + _noise(clean.shape, 0.01, 8) + burst * hit[None, :, None, :, None]
    d = diagnose(EffectModel(ctx, meas, clean), [NoiseFloor()], max_rounds=1)
    assert d.adopted == []
    (c,) = d.last_candidates
    assert c.score > 0 and c.slot_share < 0.5
    # the same power spread over every chirp is a noise floor
    meas = clean + _noise(clean.shape, 0.01, 8) + burst * np.sqrt(2 / 16)
    d = diagnose(EffectModel(ctx, meas, clean), [NoiseFloor()], max_rounds=1)
    assert d.adopted == ["noise_floor"]


def test_10_an_if_filter_is_scored_on_every_chirp_a_gain_on_the_chirp_average():
    """Chirp-static candidates are scored on the chirp average, except one that
    shapes the receiver noise (the IF filter): averaging buries its noise
    notch under what the scene leaves unexplained, so it is scored on every
    chirp (the held-out sample count says which data a score saw)."""
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.residual.ranking import _Tiers

    radar = RadarConfig.awr1843(num_chirps=8, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    meas = clean * 1.01 + _noise(clean.shape, 0.02, 14)
    model = EffectModel(ctx, meas, clean)
    tiers = _Tiers(model, 3, 0, "auto")
    scores = {c.name: c for c in tiers.rank([IFFilter(), ChannelGain()], 1.0, 50, None)}
    # (a candidate raced out after its first fold has seen a third of them)
    held_out = {k: c.gain / c.gain_per_sample * 3 / len(c.fold_gains) for k, c in scores.items()}
    assert held_out["if_filter"] == pytest.approx(clean.size)
    assert held_out["channel_gain"] == pytest.approx(clean.size / radar.num_chirps)


def test_10b_an_if_filter_must_predict_the_held_out_noise_it_shapes():
    """Two targets behind a first-order high-pass (corner 3 bins; truth:
    ``scipy.signal.freqs`` per target): with the receiver noise through the
    same high-pass (``scipy.signal.lfilter``) the filter's held-out gain on
    the chirp-to-chirp scatter is large; with the noise added after it (a
    response on the mean alone, which any smooth complex gain over beat
    frequency could be) it is nothing, and the filter is not acceptable
    however much of the mean it explains."""
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.residual.ranking import _shapes_held_out_noise, _Tiers

    radar = RadarConfig.awr1843(num_chirps=8, num_samples=64)
    ctx = EffectContext(radar)
    f_hp = 3 * radar.sample_rate / radar.num_samples
    amps, ranges = np.array([1.0, 0.4j]), np.array([1.8, 3.7])
    f_b = 2 * ranges * radar.slope / C
    _, H = signal.freqs([1.0, 0.0], [1.0, 2 * np.pi * f_hp], worN=2 * np.pi * f_b)
    clean = _clean(radar)
    filtered = synthesize_adc(radar, amps * H, 2 * ranges / C)[None]
    white = _noise(clean.shape, 0.02, 15)
    shaped = highpass_noise(white, f_hp, radar.sample_rate)
    gains = {}
    for name, noise in (("shaped", shaped), ("white", white)):
        model = EffectModel(ctx, filtered + noise, clean)
        (score,) = _Tiers(model, 3, 0, "auto").rank([IFFilter(highpass_stages=1)], 1.0, 80,
                                                     None)
        gains[name] = score
    # measured: 2844 nats, 646 of them (less one parameter's 5) on the scatter;
    # 2180 nats, 0.04 on the scatter
    assert gains["shaped"].noise_gain > 100 and _shapes_held_out_noise(gains["shaped"])
    assert gains["white"].gain > 100                     # the mean response alone
    assert gains["white"].noise_gain < 0 and not _shapes_held_out_noise(gains["white"])


def test_10c_an_if_filter_must_shape_the_noise_of_most_transmit_slots():
    """Two targets behind a first-order high-pass (as in test 10b).  Receiver
    noise through the high-pass is in every transmission; a burst of
    high-passed noise in two of the 24 transmit slots over white receiver
    noise (an interferer; truth: the planted slots) is scatter with a
    spectrum too, and the filter gains held-out nats on it, but only in the
    slots the burst hit: it is not acceptable (:func:`_stationary_shaper`)."""
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.residual.ranking import (
        _shapes_held_out_noise, _stationary_shaper, _Tiers, required_slot_share)

    radar = RadarConfig.awr1843(num_chirps=8, num_samples=64)
    ctx = EffectContext(radar)
    f_hp = 3 * radar.sample_rate / radar.num_samples
    amps, ranges = np.array([1.0, 0.4j]), np.array([1.8, 3.7])
    _, H = signal.freqs([1.0, 0.0], [1.0, 2 * np.pi * f_hp],
                        worN=2 * np.pi * 2 * ranges * radar.slope / C)
    filtered = synthesize_adc(radar, amps * H, 2 * ranges / C)[None]
    white = _noise(filtered.shape, 0.02, 15)
    burst = np.zeros_like(white)
    for t, c in ((0, 2), (2, 5)):                    # two (Tx, chirp) slots
        burst[0, t, :, c] = highpass_noise(_noise(white[0, t, :, c].shape, 0.3, 16 + t),
                                           f_hp, radar.sample_rate)
    needed = required_slot_share(3 * 8)              # 0.70
    scores = {}
    for name, noise in (("every slot", highpass_noise(white, f_hp, radar.sample_rate)),
                        ("burst", white + burst)):
        model = EffectModel(ctx, filtered + noise, _clean(radar))
        (scores[name],) = _Tiers(model, 3, 0, "auto").rank([IFFilter(highpass_stages=1)],
                                                            1.0, 80, None)
    # measured: 645 nats on the scatter in 24 / 24 slots; 281 nats in 2 / 24
    every, burst = scores["every slot"], scores["burst"]
    assert every.noise_gain > 100 and every.slot_share >= needed
    assert _stationary_shaper(every, needed)
    assert _shapes_held_out_noise(burst)             # gains on the scatter ...
    assert burst.slot_share < needed                 # ... in the burst's slots only
    assert not _stationary_shaper(burst, needed)


def test_10d_a_filter_beside_an_adopted_leakage_meets_a_base_refitted_like_it():
    """Two targets and a Tx->Rx leakage (0.12 m, each channel's amplitude 20 %
    off the separable pattern) behind a first-order high-pass, the receiver
    noise through it too (truth: ``scipy.signal.freqs`` per tone,
    ``lfilter`` for the noise).  The leakage is adopted first (fitted on
    every channel); the IF filter scored next refits it behind itself on the
    training channels only.  Its fold base refits the leakage there too, so
    the filter is judged on what it adds, not on the channels the adopted
    leakage had seen (measured: +434 held-out nats against such bases,
    -306 on the first fold against the adopted leakage)."""
    from sionna_mmir.effects.library.coupling import Coupling
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.residual.ranking import _Tiers

    radar = RadarConfig.awr1843(num_chirps=8, num_samples=64)
    ctx = EffectContext(radar)
    f_hp = 3 * radar.sample_rate / radar.num_samples

    def hp(f):
        return signal.freqs([1.0, 0.0], [1.0, 2 * np.pi * f_hp], worN=2 * np.pi * f)[1]

    amps, ranges = np.array([1.0, 0.4j]), np.array([1.8, 3.7])
    filtered = synthesize_adc(radar, amps * hp(2 * ranges * radar.slope / C), 2 * ranges / C)[None]
    T, R = radar.num_tx, radar.num_rx
    rng = np.random.default_rng(3)
    a = 3.0 * (1 + 0.2 * (rng.normal(size=(T, R)) + 1j * rng.normal(size=(T, R))) / np.sqrt(2))
    f_l = 2 * 0.12 * radar.slope / C
    t = np.arange(radar.num_samples) / radar.sample_rate
    leak = (a[..., None] * hp(np.array([f_l])) * np.exp(2j * np.pi * f_l * t))[None, :, :, None]
    noise = highpass_noise(_noise(filtered.shape, 0.02, 15), f_hp, radar.sample_rate)
    m = EffectModel(ctx, filtered + leak + noise, _clean(radar))
    m.add(Coupling())
    m.fit()
    (score,) = _Tiers(m, 3, 0, "auto").rank([IFFilter(highpass_stages=1)], 1.0, 80, None)
    assert score.gain > 100 and score.noise_gain > 100, score


def test_11_the_unexplained_rest_is_measured_against_a_robust_noise_level():
    """White noise alone is not an unexplained rest; bursts in a third of the
    transmit slots are, and are localised in slow time.  Truth: the planted
    noise power and burst slots (a model's fitted white floor would be the
    mean residual power and hide any rest)."""
    from sionna_mmir.residual.localise import localise, robust_noise_power

    radar = RadarConfig.awr1843(num_chirps=16, num_samples=64)
    ctx = EffectContext(radar)
    shape = (1, radar.num_tx, radar.num_rx, radar.num_chirps, radar.num_samples)
    noise = _noise(shape, 0.5, 21)
    assert robust_noise_power(noise) == pytest.approx(0.25, rel=0.05)
    quiet = localise(ctx, noise)
    assert abs(quiet["excess_db"]) < 0.2 and not quiet["significant"]
    hit = np.zeros(shape[:4] + (1,), bool)
    hit[0, :, :, ::3] = True                                 # every third chirp loop
    burst = _noise(shape, 1.5, 22) * hit
    loud = localise(ctx, noise + burst)
    assert loud["significant"] and loud["excess_db"] > 3.0
    assert loud["spread_db"]["chirp"] > 3.0
    assert {c["chirp"] for c in loud["chirps"]} <= set(range(0, 16, 3))
    # bursts in one Tx's transmission of every loop: even per chirp loop,
    # uneven per transmit slot
    one_tx = np.zeros(shape[:4] + (1,), bool)
    one_tx[0, 1] = True
    slotted = localise(ctx, noise + _noise(shape, 1.5, 23) * one_tx)
    assert slotted["significant"] and slotted["spread_db"]["chirp"] < 1.0
    assert slotted["spread_db"]["slot"] > 3.0
    assert {s["tx"] for s in slotted["slots"]} == {1}


def test_12_a_weak_walker_is_adopted_beside_a_strong_static_point_the_scene_lacks():
    """One frame of 16 chirp loops: a static point 40 dB stronger than a walker
    is missing from the scene.  The missing scatterer takes the static point,
    the mover the walker at its range and speed, although the walker (-16 dB
    per sample under the noise) explains less than a tenth of a nat per
    sample (truth: the planted targets)."""
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer

    radar = RadarConfig.awr1843(num_chirps=16, num_samples=64)
    ctx = EffectContext(radar)
    assert MovingScatterer().gain_floor(ctx) == 0.0
    assert MovingScatterer().gain_floor(EffectContext(RadarConfig.awr1843(num_chirps=1),
                                                      num_frames=4, frame_period=0.02)) == 0.1
    clean = _clean(radar)
    static = synthesize_adc(radar, np.array([0.8]), np.array([2 * 2.6 / C]))[None]
    t = radar.chirp_start_times()[None, :, None, :, None]                   # [1, T, 1, C, 1]
    v, r = 1.0, 3.1
    walker = synthesize_adc(radar, np.array([0.008]), np.array([2 * r / C]))[None] * np.exp(
        4j * np.pi * radar.start_frequency * v * t / C)
    y = clean + static + walker + _noise(clean.shape, 0.03, 4)
    d = diagnose(EffectModel(ctx, y, clean), [MissingScatterer(), MovingScatterer()],
                 max_rounds=3)
    names = [a.name for a in d.adoptions]
    assert "missing_scatterer" in names and "moving_scatterer" in names, names
    mover = next(a for a in d.adoptions if a.name == "moving_scatterer").params
    assert mover["range_m"][0] == pytest.approx(r, abs=0.1)
    assert mover["velocity_m_s"][0] == pytest.approx(v, abs=0.15)


@pytest.mark.parametrize("planted", ["frequency_offset", "delay_offset"])
def test_13_the_simpler_of_two_sensor_effects_that_explain_the_same_is_adopted(planted):
    """The scene places one of two points 0.3 deg off (a misfit that per-Tx
    and per-Rx delays mimic as a phase screen, and a missing scatterer in
    part).  A planted beat-frequency offset (1 number) is adopted, not the
    delays (7), which gain a little more by also steering that point; planted
    per-Tx / per-Rx delays are still adopted as delays (truth: the planted
    effect; hand delays and phases)."""
    from helpers import direct_adc, point_target_delays
    from sionna_mmir.effects.library.delay_offset import DelayOffset
    from sionna_mmir.effects.library.frequency_offset import FrequencyOffset
    from sionna_mmir.effects.library.scatterer import unit_vectors

    radar = RadarConfig.awr1843(num_chirps=2, num_samples=64)
    ctx = EffectContext(radar)

    def scene(az):
        return sum(direct_adc(radar, a, point_target_delays(radar, r * unit_vectors(b)))
                   for r, b, a in ((2.0, 0.0, 1.0), (3.3, az, 0.6j)))[None]

    rng = np.random.default_rng(0)
    t = ctx.fast_time
    if planted == "frequency_offset":
        phase = 2 * np.pi * 3e3 * t
    else:
        T, R = radar.num_tx, radar.num_rx
        dtau = (rng.uniform(-60, 60, T)[:, None] + rng.uniform(-60, 60, R)[None]) * 1e-12
        phase = (2 * np.pi * (radar.start_frequency + radar.slope * t)
                 * dtau[None, :, :, None, None])
    y = scene(20.3) * np.exp(1j * phase) + _noise((1,) + scene(20.0).shape[1:], 0.01, 0)
    d = diagnose(EffectModel(ctx, y, scene(20.0)),
                 [DelayOffset(), FrequencyOffset(), MissingScatterer()], max_rounds=1)
    assert d.adopted == [planted], [(c.name, c.gain) for c in d.adoptions[0].candidates]
    gains = {c.name: c.gain for c in d.adoptions[0].candidates}
    if planted == "frequency_offset":      # the delays do gain more: the rule decides
        assert gains["delay_offset"] > gains["frequency_offset"] > 0.9 * gains["delay_offset"]


def _floorless(*effects) -> list:
    """``effects`` as a candidate pool without gain floors (every held-out
    gain counts), for ranking tests on fixed scores."""
    for e in effects:
        e.gain_floor = lambda ctx: 0.0
    return list(effects)


class _FixedTiers:
    """Stand-in for ``ranking._Tiers`` with fixed ``{name: (gain, n_params)}``
    held-out gains, one held-out sample each (penalty 1 nat a parameter)."""

    def __init__(self, gains, tests=None):
        self.model = type("M", (), {"ctx": None})()
        self.gains, self.tests = gains, tests or {}

    def object_test(self, effect, n_params, penalty, maxiter):
        return self.tests.get(effect.name, {"shared": -np.inf, "own": 0.0, "penalty": n_params})

    def rank(self, group, penalty, maxiter, progress):
        from sionna_mmir.residual.ranking import CandidateScore

        return [CandidateScore(e.name, n, g, g / 1e4, g - n, [g])
                for e in group for (name, (g, n)) in self.gains.items() if name == e.name]

    def on_one_scale(self, ranking, best, *args):
        return ranking, best


def test_14_a_sensor_effect_must_beat_the_scene_side_by_a_margin():
    """``_rank_round`` on fixed held-out gains: a sensor effect that beats the
    best scene-side candidate by less than ``SCENE_MARGIN`` of its gain gives
    way to it; by more, it is adopted; unacceptable scene candidates (gain
    under their floor) do not count; then the parsimony rule picks among
    sensor effects."""
    from sionna_mmir.effects.library.coupling import Coupling
    from sionna_mmir.effects.library.delay_offset import DelayOffset
    from sionna_mmir.effects.library.frequency_offset import FrequencyOffset
    from sionna_mmir.residual.ranking import SCENE_MARGIN, _rank_round

    pool = _floorless(ChannelGain(), MissingScatterer(), DelayOffset(), FrequencyOffset(),
                      Coupling())
    just_under = (1 - SCENE_MARGIN) * 1000 - 5
    cases = [({"channel_gain": (1000, 14), "missing_scatterer": (just_under + 10, 5)},
              "missing_scatterer"),
             ({"channel_gain": (1000, 14), "missing_scatterer": (just_under, 5)}, "channel_gain"),
             ({"delay_offset": (1000, 28), "frequency_offset": (950, 4),
               "missing_scatterer": (100, 5)}, "frequency_offset"),
             ({"delay_offset": (1000, 28), "frequency_offset": (950, 4),
               "missing_scatterer": (20, 5)}, "delay_offset"),
             ({"delay_offset": (1000, 28), "frequency_offset": (850, 4),
               "missing_scatterer": (100, 5)}, "delay_offset")]
    for gains, expected in cases:
        _, best = _rank_round(_FixedTiers(gains), pool, 1.0, 10, None, 0.0, set())
        assert best.name == expected, (gains, best.name)
    pool[1].gain_floor = lambda ctx: 1.0             # the scatterer is not acceptable
    _, best = _rank_round(_FixedTiers(cases[0][0]), pool, 1.0, 10, None, 0.0, set())
    assert best.name == "channel_gain"


def test_14g_a_scene_side_candidate_too_costly_to_adopt_still_holds_a_sensor_effect_back():
    """``_rank_round`` on fixed held-out gains: object patterns that predict
    the held-out channels better than a per-channel gain, with more
    parameters than their gain pays for (negative score), are not adopted,
    but the gain is not either: the round takes an acceptable scene-side
    candidate instead, or the next sensor effect they do not reach, or
    nothing.  With the rule as it was (acceptable scene candidates only) the
    gain is adopted in the first case."""
    from sionna_mmir.effects.library.coupling import Coupling
    from sionna_mmir.effects.library.scene_mismatch import ObjectPattern
    from sionna_mmir.residual.ranking import _rank_round

    pool = _floorless(ChannelGain(), MissingScatterer(), ObjectPattern(), Coupling())
    gain, patterns = (107.4, 14), (146.5, 420)       # the hall's clean control, parameters x10
    cases = [({"channel_gain": gain, "object_pattern": patterns}, None),
             ({"channel_gain": gain, "object_pattern": patterns, "missing_scatterer": (30, 5)},
              "missing_scatterer"),
             ({"channel_gain": gain, "object_pattern": patterns, "coupling": (200, 120)},
              "coupling"),
             ({"channel_gain": gain, "object_pattern": patterns, "coupling": (150, 100)}, None),
             ({"channel_gain": gain, "object_pattern": (90.0, 420)}, "channel_gain"),
             ({"channel_gain": gain, "object_pattern": (146.5, 100)}, "object_pattern")]
    for gains, expected in cases:
        _, best = _rank_round(_FixedTiers(gains), pool, 1.0, 10, None, 0.0, set())
        assert (best and best.name) == expected, (gains, best)
    pool[2].gain_floor = lambda ctx: 1.0             # patterns under their floor do not count
    _, best = _rank_round(_FixedTiers(cases[0][0]), pool, 1.0, 10, None, 0.0, set())
    assert best.name == "channel_gain"


def test_14i_a_gain_the_objects_agree_on_is_not_held_back_by_their_patterns():
    """``_rank_round`` on fixed held-out gains (the seed-3 room's first round:
    a per-channel gain 6 021 nats with 14 parameters, object patterns 5 572
    with 28, inside the scene margin) and fixed held-out object tests
    (``shared``: the strongest object's pattern on the second; ``own``: the
    second's own pattern; penalty 14 nats here).  The gain is adopted only
    when the shared pattern gains over twice its penalty and 0.8 of the own
    one (the measured seed-3 gain: 1 025 of 1 032); held back for the
    patterns when it gains less than that (a clean room: -89 of 9) or is
    only partly common (the cascade's clean room: 0.43 of the own gain);
    the test is kept on the patterns' entry.  Without it the patterns are
    adopted every time."""
    from sionna_mmir.effects.library.scene_mismatch import ObjectPattern
    from sionna_mmir.residual.ranking import _rank_round

    pool = _floorless(ChannelGain(), ObjectPattern(), MissingScatterer())
    gains = {"channel_gain": (6021.0, 14), "object_pattern": (5572.0, 28)}
    for shared, own, expected in ((1025.0, 1032.0, "channel_gain"), (-89.0, 9.0, "object_pattern"),
                                  (20.0, 21.0, "object_pattern"),
                                  (430.0, 1000.0, "object_pattern")):
        test = {"shared": shared, "own": own, "penalty": 14.0}
        ranking, best = _rank_round(_FixedTiers(gains, {"object_pattern": test}), pool, 1.0,
                                    10, None, 0.0, set())
        assert best.name == expected, (shared, own, best)
        (pattern,) = [c for c in ranking if c.name == "object_pattern"]
        assert pattern.object_test == test
    gains["missing_scatterer"] = (5500.0, 5)          # another scene-side candidate in reach
    test = {"shared": 1025.0, "own": 1032.0, "penalty": 14.0}
    _, best = _rank_round(_FixedTiers(gains, {"object_pattern": test}), pool, 1.0, 10, None,
                          0.0, set())
    assert best.name == "channel_gain"


def test_14j_a_gain_that_leads_must_still_be_shared_by_the_objects():
    """``_rank_round`` on fixed held-out gains where a per-channel gain leads
    the object patterns by more than the scene margin (the AWR1843 hall of
    seed 4, pose-offset run, round 2: 259 against 223 nats), so the patterns
    are not within reach.  The gain is adopted only when the held-out
    object shares its pattern (a planted gain: 0.89-0.99 of the own
    pattern); when it does not (a clean room: under one penalty, or 0.43
    of the own gain) the gain is held and the best scene-side candidate
    goes first.  Without a pattern candidate in the pool, or without a
    second object to ask (``shared`` = -inf), the gain is judged as before."""
    from sionna_mmir.effects.library.scene_mismatch import ObjectPattern
    from sionna_mmir.residual.ranking import _rank_round

    gains = {"channel_gain": (259.0, 14), "object_pattern": (223.0, 28),
             "missing_scatterer": (133.0, 5)}
    for shared, own, expected in ((950.0, 1000.0, "channel_gain"),
                                  (-5.0, 9.0, "object_pattern"),
                                  (430.0, 1000.0, "object_pattern"),
                                  (-np.inf, 0.0, "channel_gain")):
        pool = _floorless(ChannelGain(), ObjectPattern(), MissingScatterer())
        test = {"shared": shared, "own": own, "penalty": 14.0}
        ranking, best = _rank_round(_FixedTiers(gains, {"object_pattern": test}), pool, 1.0,
                                    10, None, 0.0, set())
        assert best.name == expected, (shared, own, best)
    pool = _floorless(ChannelGain(), MissingScatterer())   # no twin to ask
    test = {"shared": -5.0, "own": 9.0, "penalty": 14.0}
    _, best = _rank_round(_FixedTiers(gains, {"object_pattern": test}), pool, 1.0, 10, None,
                          0.0, set())
    assert best.name == "channel_gain"


def test_14h_a_fold_fit_in_a_bad_basin_restarts_from_the_best_fold(monkeypatch):
    """End to end through the fold fits (serial): a planted per-channel gain,
    its fit on fold 0 made to end in a bad basin (its held-out and training
    NLL raised by hand). The fold is fitted again from the best fold's
    values and that fit replaces it, since it fits the training cells
    better: the score is the one of three clean folds (the same fits,
    within the optimiser's tolerance). When the bad fit claims the lower
    training NLL, it stays, whatever it does on the held-out cells."""
    from sionna_mmir.residual import ranking

    radar = RadarConfig.awr1843(num_chirps=1, num_samples=64)   # one loop: no race
    ctx = EffectContext(radar)
    clean = _clean(radar)
    rng = np.random.default_rng(3)
    gt, gr = (np.exp(rng.normal(0, 0.2, n) + 1j * rng.uniform(-1, 1, n)) for n in (3, 4))
    g = gt[:, None] * gr[None, :]                    # separable, as the effect models it
    meas = clean * g[None, :, :, None, None] + _noise(clean.shape, 0.01, 4)
    model = EffectModel(ctx, meas, clean)
    folds = cv_folds(ctx.shape[:4], 3)
    real = ranking._candidate_task
    (honest,) = ranking.rank_candidates(model, [ChannelGain()], folds, maxiter=60)
    assert min(honest.fold_gains) > 0

    def stuck(train_shift):
        calls = []

        def task(shared, g_, k, eff, maxiter, deviation, i=0, start=None):
            out = real(shared, g_, k, eff, maxiter, deviation, i, start)
            calls.append((k, start is not None))
            if k == 0 and start is None:             # the first fit of fold 0 ends badly
                out["nll"] += 50.0                   # nats per held-out sample
                out["train_nll"] += train_shift
            return out
        return task, calls

    task, calls = stuck(+1.0)
    monkeypatch.setattr(ranking, "_candidate_task", task)
    (score,) = ranking.rank_candidates(model, [ChannelGain()], folds, maxiter=60)
    assert calls == [(0, False), (1, False), (2, False), (0, True)]
    assert score.gain == pytest.approx(honest.gain, rel=0.02)
    task, calls = stuck(-1.0)                        # the bad fit fits training best
    monkeypatch.setattr(ranking, "_candidate_task", task)
    (score,) = ranking.rank_candidates(model, [ChannelGain()], folds, maxiter=60)
    assert calls[-1] == (0, True) and score.fold_gains[0] < -max(score.fold_gains[1:])


def test_14b_a_candidates_fitted_floor_is_held_against_its_gain():
    """The ranking takes the larger of an effect's own gain floor and the
    floor its fits called for (:attr:`CandidateScore.gain_floor`): a mover
    whose fit moves as the static scene does is not adopted under the
    scatterer floor, a sensor effect then is (truth: the fixed gains)."""
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.residual.ranking import CandidateScore, _rank_round

    class Tiers:
        model = type("M", (), {"ctx": EffectContext(RadarConfig.awr1843(num_chirps=16))})()

        def __init__(self, floor):
            self.floor = floor

        def rank(self, group, penalty, maxiter, progress):
            return [CandidateScore(e.name, 1, g, g / 1e4, g - 1, [g],
                                   gain_floor=self.floor if e.name == "moving_scatterer" else 0.0)
                    for e, g in zip(group, (3000.0, 400.0))]

        def on_one_scale(self, ranking, best, *args):
            return ranking, best

    pool = [MovingScatterer(), ChannelGain()]
    _, best = _rank_round(Tiers(0.0), pool, 1.0, 10, None, 0.0, set())
    assert best.name == "moving_scatterer"               # 0.3 nats per sample, no floor
    _, best = _rank_round(Tiers(0.5), pool, 1.0, 10, None, 0.0, set())
    assert best.name == "channel_gain"                   # under the floor its fit called for


def test_14c_fold_fits_report_the_floor_of_a_static_looking_mover():
    """End to end through the fold fits: a radar approaching at 0.6 m/s, a
    static point the scene lacks; with ego motion adopted, the mover fitted
    to that point moves at the static scene's velocity and its score carries
    the scatterer floor; the same point moving on its own does not (truth:
    the planted delays of ``direct_adc``)."""
    from helpers import direct_adc, point_target_delays
    from sionna_mmir.effects.library.ego_motion import EgoMotion
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.effects.library.scatterer import unit_vectors
    from sionna_mmir.residual.ranking import rank_candidates

    radar = RadarConfig.awr1843(num_chirps=16, num_samples=64)
    ctx = EffectContext(radar)
    v = 0.6

    def point(r, az, rate, amp):
        return direct_adc(radar, amp, point_target_delays(radar, r * unit_vectors(az)), rate)[None]

    base = point(3.3, 0.0, -2 * v / C, 1.0)               # the scene, seen from the moving radar
    static = point(2.4, 30.0, -2 * v * np.cos(np.radians(30.0)) / C, 0.05)
    walker = point(2.4, 30.0, 2 * 1.0 / C, 0.05)
    folds = cv_folds(ctx.shape[:4], 3)
    for extra, floor in ((static, 0.1), (walker, 0.0)):
        y = base + extra + _noise(base.shape, 0.01, 7)
        m = EffectModel(ctx, y, point(3.3, 0.0, 0.0, 1.0))
        ego = m.add(EgoMotion())
        ego.values["velocity"] = np.array([v])
        (score,) = rank_candidates(m, [MovingScatterer()], folds, maxiter=40)
        assert score.gain > 0
        assert score.gain_floor == pytest.approx(floor), (floor, score)


def test_14d_candidates_on_every_chirp_race_on_their_first_fold():
    """On a model fitted on every chirp of several chirp loops a candidate is
    fitted on its first fold, and on the others only when its held-out gain
    there is positive: a walker the scene lacks keeps all three folds and
    the same fold gains as without the race; a channel gain with nothing to
    explain stops after a non-positive first fold, with that fold's gain; on
    the chirp average nothing races (truth: the scores of the same fits run
    on every fold, ``race=False``)."""
    from helpers import direct_adc, point_target_delays
    from sionna_mmir.effects.library.dc_offset import DCOffset
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.effects.library.scatterer import unit_vectors
    from sionna_mmir.residual.ranking import rank_candidates

    radar = RadarConfig.awr1843(num_chirps=16, num_samples=64)
    ctx = EffectContext(radar)

    def point(r, az, rate, amp):
        return direct_adc(radar, amp, point_target_delays(radar, r * unit_vectors(az)), rate)[None]

    base = point(3.3, 0.0, 0.0, 1.0)
    y = base + point(2.4, 30.0, 2 * 1.0 / C, 0.05) + _noise(base.shape, 0.01, 7)
    m = EffectModel(ctx, y, base)
    folds = cv_folds(ctx.shape[:4], 3)
    cands = [MovingScatterer(), ChannelGain(), DCOffset()]
    full = {c.name: c for c in rank_candidates(m, cands, folds, maxiter=40, race=False)}
    raced = {c.name: c for c in rank_candidates(m, cands, folds, maxiter=40)}
    assert full["moving_scatterer"].gain > 1e4
    assert full["channel_gain"].fold_gains[0] <= 0 < full["dc_offset"].fold_gains[0]
    for name, c in full.items():
        r = raced[name]
        if c.fold_gains[0] > 0:
            assert r.fold_gains == pytest.approx(c.fold_gains, rel=1e-6, abs=1e-6)
        else:
            assert r.fold_gains == pytest.approx(c.fold_gains[:1], rel=1e-6, abs=1e-6)
            assert r.score <= 0
    avg = m.chirp_averaged()
    avg_folds = cv_folds(avg.ctx.shape[:4], 3)
    (gain,) = rank_candidates(avg, [ChannelGain()], avg_folds, maxiter=40)
    assert len(gain.fold_gains) == 3


def test_14e_a_noise_shaper_must_gain_more_than_the_noise_models():
    """When the best mean candidate shapes the receiver noise (an IF filter),
    the noise models are scored in the same round and an acceptable one that
    gains more is chosen instead; one that gains less, or is not acceptable,
    leaves the filter chosen (truth: the rule, on given scores)."""
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.effects.library.phase_noise import PhaseNoise
    from sionna_mmir.residual.ranking import CandidateScore, _noise_before_shaper

    def score(name, gain):
        return CandidateScore(name=name, n_params=1, gain=gain, gain_per_sample=gain,
                              score=gain, fold_gains=[gain])

    class _Tiers:
        def __init__(self, scores):
            self.scores, self.asked = scores, []

        def rank(self, candidates, *args):
            self.asked += [c.name for c in candidates]
            return [self.scores[c.name] for c in candidates]

    pool = [IFFilter(), NoiseFloor(), PhaseNoise(), ChannelGain()]
    shaper = score("if_filter", 2709.0)
    for floor_gain, fine, chosen in ((198_000.0, True, "noise_floor"),
                                     (1_000.0, True, "if_filter"),
                                     (198_000.0, False, "if_filter")):
        tiers = _Tiers({"noise_floor": score("noise_floor", floor_gain),
                        "phase_noise": score("phase_noise", -5.0)})
        ok = (lambda c: c.score > 0 and (fine or c.name != "noise_floor"))
        ranking, best = _noise_before_shaper(tiers, pool, [shaper], shaper, ok, {}, ())
        assert sorted(tiers.asked) == ["noise_floor", "phase_noise"]
        assert best.name == chosen
        assert {c.name for c in ranking} == {"if_filter", "noise_floor", "phase_noise"}
    # screened noise models are not scored
    tiers = _Tiers({})
    _, best = _noise_before_shaper(tiers, pool, [shaper], shaper, lambda c: True,
                                   {"noise_floor": "white", "phase_noise": "static"}, ())
    assert best is shaper and tiers.asked == []


def test_14f_an_effect_on_every_path_must_follow_the_signal_across_range():
    """``outside_share`` on hand-made bins, then on data: a per-channel gain on
    every path removes held-out residual at every object, one shared by the
    two strongest objects only (what per-object patterns are) makes the third
    worse and is not acceptable.  Truth: the planted gains."""
    from sionna_mmir.residual.ranking import (OUTSIDE_TOLERANCE, CandidateScore, _rank_round,
                                              outside_share, rank_candidates)

    N = 64
    power = np.zeros(N)
    power[[10, 30, 50]] = 8.0, 7.0, 3.0                # the first two hold >= half: inside
    base = np.full(N, 1.0)
    cand = base - 0.01 * power                         # in proportion to the power
    assert outside_share(base, cand, power) == pytest.approx(0.03 / 0.15)
    cand = base.copy()
    cand[[10, 30]] -= 0.1
    cand[50] += 0.05                                   # the third object made worse
    assert outside_share(base, cand, power) == pytest.approx(-0.25)
    cand[[10, 30]] = base[[10, 30]]                    # nothing removed at the objects
    assert outside_share(base, cand, power) == -np.inf
    assert outside_share(base, base, power) == 0.0

    class Tiers:
        model = type("M", (), {"ctx": type("X", (), {"shape": (1, 3, 4, 1, 64)})()})()

        def rank(self, group, penalty, maxiter, progress):
            return [CandidateScore(e.name, 1, 1000.0, 0.1, 999.0, [1000.0],
                                   energy_change_db=-1.0, outside_share=-0.3)
                    for e in group if e.name == "channel_gain"]

        def on_one_scale(self, ranking, best, *args):
            return ranking, best

    pool = [ChannelGain()]
    pool[0].gain_floor = lambda ctx: 0.0
    assert _rank_round(Tiers(), pool, 1.0, 10, None, 0.0, set())[1] is None

    radar = RadarConfig.awr1843(num_chirps=1, num_samples=64)
    ctx = EffectContext(radar)
    amps, ranges = np.array([1.0, 0.95j, 0.9]), np.array([1.8, 2.7, 3.7])
    paths = [synthesize_adc(radar, amps[i:i + 1], 2 * ranges[i:i + 1] / C)[None]
             for i in range(3)]
    clean = sum(paths)
    g = np.random.default_rng(9)
    gains = (1 + 0.2 * (g.normal(size=(3, 1)) + 1j * g.normal(size=(1, 4))))[None, :, :, None, None]
    shares = {}
    for case, y in {"every path": clean * gains,
                    "two objects": (paths[0] + paths[1]) * gains + paths[2]}.items():
        m = EffectModel(ctx, y + _noise(clean.shape, 0.01, 10), clean)
        m.fit(trainable=[])
        (c,) = rank_candidates(m, [ChannelGain()], cv_folds(ctx.shape[:4], 3))
        assert c.gain > 0, (case, c)
        shares[case] = c.outside_share
    assert shares["every path"] > 0.2, shares
    assert shares["two objects"] < -OUTSIDE_TOLERANCE, shares


def test_15_a_noise_model_is_scored_on_the_chirp_to_chirp_scatter():
    """Phase noise (a stationary variance model) is scored on the residual's
    chirp-to-chirp deviation: a static misfit of the scene (a target 25 %
    stronger and 4 mm farther than the model has it) gains it nothing, while
    real LO phase noise on every chirp does (truth: the planted misfit and
    phase-noise draws).  Scored on the whole residual the static misfit
    gained it ~14 600 nats."""
    from test_effects_sensor import _phase_noise_draws

    from sionna_mmir.effects.library.phase_noise import PhaseNoise
    from sionna_mmir.residual.ranking import rank_candidates

    radar = RadarConfig.awr1843(num_chirps=8, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    folds = cv_folds(ctx.shape[:4], 3)

    def gain(meas):
        m = EffectModel(ctx, meas, clean)
        m.fit(trainable=[])
        (c,) = rank_candidates(m, [PhaseNoise()], folds)
        return c.gain

    true = synthesize_adc(radar, np.array([1.25, 0.4j]), 2 * np.array([1.804, 3.7]) / C)[None]
    assert gain(true + _noise(clean.shape, 3e-3, 21)) < 0
    F, T, _, Cn, N = ctx.shape
    phi = _phase_noise_draws(np.random.default_rng(22), (F, T, 1, Cn), N, -35.0, 2.0)
    assert gain(clean * np.exp(1j * phi) + _noise(clean.shape, 3e-3, 21)) > 100


def test_15b_a_noise_model_is_fitted_on_the_scatter_it_is_scored_on():
    """Real LO phase noise beside a static misfit of the scene 20 dB above
    the noise: a noise model fitted to the whole residual widens its
    variance where the misfit is and then overpredicts the chirp-to-chirp
    scatter it is scored on; fitted to that scatter (the model plus the
    residual's deviation from its chirp mean), it gains what the phase
    noise is there for.  The coloured floor likewise (truth: the planted
    misfit, phase-noise draws and shaped noise)."""
    from test_effects_sensor import _phase_noise_draws

    from sionna_mmir.effects.library.phase_noise import PhaseNoise
    from sionna_mmir.residual.ranking import rank_candidates

    radar = RadarConfig.awr1843(num_chirps=8, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    folds = cv_folds(ctx.shape[:4], 3)
    true = synthesize_adc(radar, np.array([1.25, 0.4j]), 2 * np.array([1.804, 3.7]) / C)[None]
    F, T, _, Cn, N = ctx.shape
    phi = _phase_noise_draws(np.random.default_rng(22), (F, T, 1, Cn), N, -35.0, 2.0)
    noise = _noise(clean.shape, 3e-3, 21)
    m = EffectModel(ctx, true * np.exp(1j * phi) + noise, clean)
    m.fit(trainable=[])
    (c,) = rank_candidates(m, [PhaseNoise()], folds)
    assert c.gain > 100, c
    b, a = signal.butter(2, 0.2)                                  # low-pass coloured noise
    coloured = signal.lfilter(b, a, _noise(clean.shape, 2e-2, 23), axis=-1)
    m = EffectModel(ctx, true + noise + coloured, clean)
    m.fit(trainable=[])
    (c,) = rank_candidates(m, [NoiseFloor()], folds)
    assert c.gain > 100, c
    assert c.slot_share > 0.9, c           # stationary: judged on the same scatter


def test_15c_an_adopted_noise_model_keeps_to_the_scatter():
    """Adopted beside a static scene misfit 20 dB above the noise, a coloured
    floor is fitted to the chirp-to-chirp scatter: its shape at the misfit's
    range bins (relative to the white bins 28-36) is the planted noise's to
    within 35 % (0.69-0.97); fitted to the whole residual it was 1.6-2.2 times too high
    there (truth: the planted white plus low-pass noise, its power per bin
    measured on the noise itself)."""
    from sionna_mmir.residual.adoption import _adopt

    radar = RadarConfig.awr1843(num_chirps=8, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    true = synthesize_adc(radar, np.array([1.25, 0.4j]), 2 * np.array([1.804, 3.7]) / C)[None]
    b, a = signal.butter(2, 0.2)
    noise = _noise(clean.shape, 3e-3, 21) + signal.lfilter(b, a, _noise(clean.shape, 2e-2, 23),
                                                            axis=-1)
    m = EffectModel(ctx, true + noise, clean)
    m.fit(trainable=[])
    _adopt(m, NoiseFloor(), 100)
    v = np.median(m.mean_variance_numpy()[1], axis=(0, 1, 2, 3))
    p = np.mean(np.abs(np.fft.fft(noise, axis=-1, norm="ortho")) ** 2, axis=(0, 1, 2, 3))
    white = slice(28, 37)
    shape = (v / np.median(v[white])) / (p / np.median(p[white]))
    k = np.argsort(np.abs(np.fft.fft(true - clean, axis=-1)).sum(axis=(0, 1, 2, 3)))[-4:]
    assert np.all(np.abs(shape[k] - 1) < 0.35), (k, shape[k])


def test_16_ego_motion_is_scored_beside_a_mover_it_makes_redundant():
    """A static scene seen from a radar moving at 0.73 m/s: a mover adopted
    first takes the strongest target at its line-of-sight speed.  Ego motion
    scored next starts from the model without that mover and may take the
    object back from it, so it gains more than a second mover does (truth:
    hand delay rates, ``direct_adc``)."""
    from test_effects_scene import _moving_frames

    from sionna_mmir.effects.library.ego_motion import EgoMotion
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.residual.ranking import rank_candidates

    radar = RadarConfig.awr1843(num_chirps=8)
    F, period, v = 2, 2e-3, 0.73
    ctx = EffectContext(radar, num_frames=F, frame_period=period)
    stat, mov = _moving_frames(radar, F, period, v)
    m = EffectModel(ctx, mov + _noise(mov.shape, 0.01, 23), stat)
    mover = m.add(MovingScatterer())
    m.fit()
    assert np.allclose(mover.values["range"], 2.0, atol=0.05)
    assert np.allclose(mover.values["velocity"], -v, atol=0.1)
    ranked = {c.name: c.gain for c in rank_candidates(m, [EgoMotion(), MovingScatterer()],
                                                      cv_folds(ctx.shape[:4], 3))}
    assert ranked["ego_motion"] > ranked["moving_scatterer"] > 0, ranked


def test_16b_ego_motion_beside_a_real_walker_refits_only_itself_and_the_walker():
    """A walker (4.5 m, -0.9 m/s) in a static scene seen from a radar at
    rest, adopted as a mover: ego motion scored next starts without the
    mover, finds the radar at rest, and the walker restored beside it
    explains the training cells better, so only ego motion and the mover
    are refitted -- not every component on every chirp -- and ego motion
    gains nothing (truth: ``direct_adc`` of the walker, the radar at rest)."""
    from helpers import direct_adc, point_target_delays
    from test_effects_scene import _scene

    from sionna_mmir.effects.library.ego_motion import EgoMotion
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.effects.library.scatterer import unit_vectors
    from sionna_mmir.residual.ranking import rank_candidates

    radar = RadarConfig.awr1843(num_chirps=16)
    ctx = EffectContext(radar)
    base = _scene(radar)[None]
    walker = direct_adc(radar, 0.3, point_target_delays(radar, 4.5 * unit_vectors(12.0)),
                        2 * -0.9 / C)[None]
    m = EffectModel(ctx, base + walker + _noise(base.shape, 0.01, 4), base)
    mover = m.add(MovingScatterer())
    m.fit()
    assert mover.values["velocity"][0] == pytest.approx(-0.9, abs=0.05)
    calls = []
    real_fit = EffectModel.fit

    def fit(self, trainable=None, *a, **k):
        calls.append(None if trainable is None else list(trainable))
        return real_fit(self, trainable, *a, **k)

    mp = pytest.MonkeyPatch()
    mp.setattr(EffectModel, "fit", fit)
    try:
        (ego,) = rank_candidates(m, [EgoMotion()], cv_folds(ctx.shape[:4], 3))
    finally:
        mp.undo()
    assert ego.score < 0, ego
    assert None not in calls and [1, 0] in calls, calls


def test_16c_ego_motion_is_scored_with_the_object_gains_refitted_beside_it():
    """Three points seen from a radar moving at 1.5 m/s, the base's object
    gains fitted to the moving capture with a static model (each takes its
    point's coherent loss over the chirp loops).  Ego motion is scored with
    those gains refitted beside it (``refit_beside``): its held-out gain is
    more than twice that of the same effect scored with them held, and above
    a mover's (truth: hand delay rates, ``direct_adc``)."""
    from helpers import direct_adc, point_target_delays
    from test_effects_scene_mismatch import _basis

    from sionna_mmir.effects.library.ego_motion import EgoMotion
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.effects.library.scatterer import unit_vectors
    from sionna_mmir.effects.library.scene_mismatch import ObjectGain
    from sionna_mmir.residual.ranking import rank_candidates

    class HeldGains(EgoMotion):
        refit_beside = ()

    radar = RadarConfig.awr1843(num_chirps=8, num_samples=128)
    v, targets = 1.5, ((2.0, 0.0, 1.0), (3.1, 25.0, 0.15j), (4.4, -35.0, 0.1))
    pts = np.array([np.reshape(r * unit_vectors(az), 3) for r, az, _ in targets])
    stat, mov = [], 0
    for (_, az, a), p in zip(targets, pts):
        tau = point_target_delays(radar, p)
        stat.append(direct_adc(radar, 1.0, tau))
        mov = mov + direct_adc(radar, a, tau, -2 * v * np.cos(np.radians(az)) / C)
    ctx = EffectContext(radar, basis=_basis(radar, np.stack(stat), pts))
    m = EffectModel(ctx, (mov + _noise(mov.shape, 0.004, 3))[None])
    m.add(ObjectGain())
    m.fit(maxiter=200)
    ranked = {c.name + ("_held" if isinstance(e, HeldGains) else ""): c.gain
              for e in (EgoMotion(), HeldGains(), MovingScatterer())
              for c in rank_candidates(m, [e], cv_folds(ctx.shape[:4], 3))}
    assert ranked["ego_motion"] > 2 * ranked["ego_motion_held"] > 0, ranked
    assert ranked["ego_motion"] > ranked["moving_scatterer"], ranked


def test_17_candidates_of_the_two_tiers_are_compared_on_the_full_data():
    """A static point the scene lacks, 16 chirp loops: scored on the chirp
    average its held-out gain is some nats; a candidate scored on every chirp
    (here a stand-in ego motion credited with twice that) would outrank it
    on the mixed scale.  ``_Tiers.on_one_scale`` scores the point again on
    the full data, where it gains more than the stand-in, and it is chosen.
    A best candidate scored with the split likelihood (an IF filter: its mean
    part is on the chirp average's scale already) is compared as it is."""
    import dataclasses as dc

    from sionna_mmir.effects.library.ego_motion import EgoMotion
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.residual.ranking import _Tiers, rank_candidates

    radar = RadarConfig.awr1843(num_chirps=16, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    point = synthesize_adc(radar, np.array([0.3]), np.array([2 * 2.6 / C]))[None]
    m = EffectModel(ctx, clean + point + _noise(clean.shape, 0.03, 24), clean)
    m.fit(trainable=[])
    tiers = _Tiers(m, 3, 0, "auto")
    pool = [EgoMotion(), MissingScatterer(), IFFilter()]
    (avg,) = rank_candidates(tiers.avg, [pool[1]], tiers.avg_folds)
    stand_in = dc.replace(avg, name="ego_motion", n_params=1, gain=2 * avg.gain,
                          score=2 * avg.gain - 1)
    ranking, best = tiers.on_one_scale([stand_in, avg], stand_in, pool, lambda c: c.score > 0,
                                       1.0, 150, None)
    assert best.name == "missing_scatterer" and best.gain > stand_in.gain, ranking
    assert best.gain_per_sample == avg.gain_per_sample      # its floor: on the average
    split = dc.replace(stand_in, name="if_filter")
    assert tiers.on_one_scale([split, avg], split, pool, lambda c: c.score > 0,
                              1.0, 150, None) == ([split, avg], split)


def test_17b_candidates_beside_an_adopted_noise_shaper_are_scored_split():
    """Once an IF filter is in the model its likelihood is split (chirp mean,
    chirp deviation over the bins of receiver noise alone): a mover scored
    beside it is compared with the base on that likelihood, and the IF filter
    as a candidate on a model without one with its base scored split too,
    the walker's bins left out of its noise shape's judgement (truth: the
    planted walker; on the cascade mover run, judged with them, an IF filter
    nobody planted gained 55 313 held-out nats)."""
    from helpers import direct_adc, point_target_delays
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.effects.library.scatterer import unit_vectors
    from sionna_mmir.residual.ranking import rank_candidates

    radar = RadarConfig.awr1843(num_chirps=8, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    walker = direct_adc(radar, 0.2, point_target_delays(radar, 3.1 * unit_vectors(20.0)),
                        2 * 1.2 / C)[None]
    y = clean + walker + _noise(clean.shape, 0.01, 5)
    folds = cv_folds(ctx.shape[:4], 3)
    m = EffectModel(ctx, y, clean)
    m.fit(trainable=[])
    # the walker's range bins carry chirp-to-chirp signal, not receiver noise:
    # the split likelihood's deviation term leaves them out
    keep = m.noise_bins()
    k = int(np.argmax(np.abs(np.fft.fft(walker[0, 0, 0, 0]))))
    assert not keep[k] and keep.sum() > 0.5 * keep.size      # its sidelobes go too
    assert EffectModel(ctx, clean + _noise(clean.shape, 0.01, 5), clean).noise_bins().all()
    (shaper,) = rank_candidates(m, [IFFilter()], folds, maxiter=20)
    assert shaper.score < 0                                  # no notch was planted
    m.add(IFFilter())
    m.fit(maxiter=20)
    assert m.split_likelihood()
    (mover,) = rank_candidates(m, [MovingScatterer()], folds, maxiter=40)
    assert mover.gain > 100, mover


def test_18_the_default_penalty_grows_with_the_held_out_samples():
    """The score charges ``ln(n) / 2`` nats per parameter (the BIC's weight; n
    the held-out complex samples the candidate was scored on), a fixed number
    when one is given; anything else is refused.  Truth: the closed form."""
    from sionna_mmir.residual.ranking import check_penalty, penalty_per_param, rank_candidates

    radar = RadarConfig.awr1843(num_chirps=2, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    gains = np.exp(1j * np.linspace(0, 1, radar.num_rx))[None, None, :, None, None]
    m = EffectModel(ctx, clean * gains + _noise(clean.shape, 0.02, 31), clean)
    m.fit(trainable=[])
    folds = cv_folds(ctx.shape[:4], 3)
    (bic,) = rank_candidates(m, [ChannelGain()], folds)
    (one,) = rank_candidates(m, [ChannelGain()], folds, penalty=1.0)
    n = bic.gain / bic.gain_per_sample
    assert n == pytest.approx(clean.size)
    assert bic.score == pytest.approx(bic.gain - 0.5 * np.log(n) * bic.n_params)
    assert one.score == pytest.approx(one.gain - one.n_params)
    assert penalty_per_param("bic", np.e ** 8) == pytest.approx(4.0)
    assert check_penalty("BIC") == "bic" and check_penalty("2.5") == 2.5
    for bad in ("aic", "nan", -1.0, float("inf"), True):
        with pytest.raises(ConfigError, match="penalty"):
            check_penalty(bad)


def test_19_a_model_that_overflows_scores_far_below_zero_instead_of_failing():
    """A candidate whose model overflows (non-finite residuals) must lose the
    ranking, not stop the loop: its held-out NLL is 1e30 per cell."""
    from sionna_mmir.effects.model import _profiled_cells

    r2 = np.ones((3, 8))
    r2[1, 2] = np.inf
    assert np.all(_profiled_cells(r2, np.ones_like(r2), np.full_like(r2, 0.1)) == 1e30)
    r2[1, 2] = np.nan
    assert np.all(_profiled_cells(r2, np.ones_like(r2), np.zeros_like(r2)) == 1e30)
    ok = _profiled_cells(np.ones((3, 8)), np.ones((3, 8)), np.zeros((3, 8)))
    assert np.allclose(ok, 1.0)                            # log(1) + 1


def test_20_a_mean_candidate_must_lower_the_held_out_residual_energy():
    """``_rank_round`` on fixed scores: a mean candidate whose held-out
    residual energy rises is not acceptable however many nats it gains (it
    raised the predicted variance instead of explaining the residual); a
    vetoed one is ranked but not chosen; variance effects and effects that
    shape the noise (an IF filter) are not held to it.  On data, a planted per-channel gain lowers the held-out residual
    energy (truth: the planted gains)."""
    from sionna_mmir.residual.ranking import CandidateScore, _rank_round, rank_candidates

    class Tiers:
        model = type("M", (), {"ctx": type("X", (), {"shape": (1, 3, 4, 8, 64)})()})()

        def __init__(self, scores):
            self.scores = scores

        def rank(self, group, penalty, maxiter, progress):
            return [self.scores[e.name] for e in group if e.name in self.scores]

        def on_one_scale(self, ranking, best, *args):
            return ranking, best

    pool = _floorless(ChannelGain(), MissingScatterer(), NoiseFloor())

    def s(name, gain, db):
        return CandidateScore(name, 1, gain, gain / 1e4, gain - 1, [gain], energy_change_db=db)

    scores = {"channel_gain": s("channel_gain", 1000, +0.5),
              "missing_scatterer": s("missing_scatterer", 500, -0.2),
              "noise_floor": s("noise_floor", 800, +0.3)}
    _, best = _rank_round(Tiers(scores), pool, 1.0, 10, None, 0.0, set())
    assert best.name == "missing_scatterer"
    _, best = _rank_round(Tiers(scores), pool, 1.0, 10, None, 0.0, set(), {"missing_scatterer"})
    assert best.name == "noise_floor"                    # the variance tier comes next
    from sionna_mmir.effects.library.if_filter import IFFilter

    pool.append(IFFilter())                              # shapes the noise: not held to it
    pool[-1].gain_floor = lambda ctx: 0.0
    scores["if_filter"] = s("if_filter", 1200, +0.2)
    _, best = _rank_round(Tiers(scores), pool, 1.0, 10, None, 0.0, set())
    assert best.name == "if_filter"

    radar = RadarConfig.awr1843(num_chirps=2, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    g = np.random.default_rng(5)
    gains = 1 + 0.3 * (g.normal(size=(3, 1)) + 1j * g.normal(size=(1, 4)))
    y = clean * gains[None, :, :, None, None] + _noise(clean.shape, 0.01, 6)
    m = EffectModel(ctx, y, clean)
    m.fit(trainable=[])
    (c,) = rank_candidates(m, [ChannelGain()], cv_folds(ctx.shape[:4], 3))
    assert c.gain > 0 and c.energy_change_db < -3.0, c


def _point_behind_gains():
    """``(ctx, clean, y)``: a point the scene lacks and per-channel gains
    (AWR1843, two chirp loops)."""
    radar = RadarConfig.awr1843(num_chirps=2, num_samples=64)
    clean = _clean(radar)
    extra = synthesize_adc(radar, np.array([0.5]), np.array([2 * 2.6 / C]))[None]
    g = np.random.default_rng(7)
    gains = 1 + 0.5 * (g.normal(size=(3, 1)) + 1j * g.normal(size=(1, 4)))
    y = (clean + extra) * gains[None, :, :, None, None] + _noise(clean.shape, 0.01, 8)
    return EffectContext(radar), clean, y


def test_21_an_adoption_whose_joint_refit_worsens_the_mean_is_undone():
    """When the joint refit after an adoption raises the residual energy, the
    model goes back to its state before the adoption, the effect is vetoed
    for the round, reported, and the next acceptable candidate is adopted
    instead (truth: the planted missing point; the overshoot is forced)."""
    from sionna_mmir.residual import diagnosis as dg
    from sionna_mmir.residual.diagnosis import DiagnosisRun

    ctx, clean, y = _point_behind_gains()
    real_adopt, events = dg._adopt, []

    def overshooting(model, eff, maxiter, fits, clock=None, **kw):
        comp = real_adopt(model, eff, maxiter, fits, **kw)
        if eff.name == "missing_scatterer":          # force a worse mean
            model.nuisance.values["gain"] = model.nuisance.values["gain"] * 3.0
        return comp

    mp = pytest.MonkeyPatch()
    mp.setattr(dg, "_adopt", overshooting)
    try:
        run = DiagnosisRun(EffectModel(ctx, y, clean), [MissingScatterer(), ChannelGain()],
                           progress=lambda e, n: events.append((e, n)))
        before = run.model.residual_energy()
        a = run.step()
    finally:
        mp.undo()
    assert [v["name"] for v in run.vetoes] == ["missing_scatterer"]     # ranked first, undone
    assert ("vetoed", "missing_scatterer") in events
    assert a.name == "channel_gain"
    assert a.before["residual_energy_db"] == pytest.approx(run.first["residual_energy_db"])
    assert run.vetoes[0]["residual_energy_db"][1] > run.vetoes[0]["residual_energy_db"][0]
    assert run.model.residual_energy() < before
    assert [c.effect.name for c in run.model.components] == ["channel_gain"]
    assert run.result().settings["vetoed"] == run.vetoes


def test_21a_a_variance_adoption_may_move_the_mean_a_little_not_by_a_decibel():
    """The mean guard by kind: a mean-only effect may not raise the residual
    energy of the joint refit by more than 0.1 dB, a noise shaper (IF filter)
    is not held to it, and a variance effect (reweighting the mean fit) may
    move it by up to 1 dB (planted phase noise and noise floor in the suite's
    AWR1843 runs: 0.000 dB)."""
    from sionna_mmir.effects.library.if_filter import IFFilter
    from sionna_mmir.effects.library.phase_noise import PhaseNoise
    from sionna_mmir.residual.adoption import MEAN_GUARD_DB, VARIANCE_GUARD_DB, _mean_worse

    def worse(eff, rise):
        return _mean_worse(eff, rise)

    assert (MEAN_GUARD_DB, VARIANCE_GUARD_DB) == (0.1, 1.0)
    assert worse(ChannelGain(), 0.2) and not worse(ChannelGain(), 0.05)
    assert not worse(IFFilter(), 3.0)
    assert not worse(PhaseNoise(), 0.5) and not worse(NoiseFloor(), 0.9)
    assert worse(PhaseNoise(), 2.1) and worse(NoiseFloor(), 1.5)


def test_21b_an_adoption_whose_refit_needs_a_higher_floor_is_undone():
    """An effect whose joint refit shows it to need a higher gain floor than
    the held-out gain per sample its candidate showed (a mover whose fold
    fits moved but whose refit comes to rest: a scatterer) is undone and
    vetoed, and the reason is reported; the next candidate is adopted.  The
    refit's floor is forced here; the rule for movers at rest is
    ``test_effects_scene::test_20e``."""
    from sionna_mmir.pipeline.report import _veto_reason
    from sionna_mmir.residual import diagnosis as dg
    from sionna_mmir.residual.diagnosis import DiagnosisRun

    ctx, clean, y = _point_behind_gains()
    refitted = []
    real_adopt = dg._adopt

    def adopt(model, eff, maxiter, fits, clock=None, **kw):
        comp = real_adopt(model, eff, maxiter, fits, **kw)
        refitted.append(eff.name)
        return comp

    point = MissingScatterer()
    mp = pytest.MonkeyPatch()
    mp.setattr(dg, "_adopt", adopt)
    mp.setattr(point, "fitted_gain_floor",
               lambda model, values: 10.0 if refitted else point.gain_floor(model.ctx))
    try:
        run = DiagnosisRun(EffectModel(ctx, y, clean), [point, ChannelGain()])
        a = run.step()
    finally:
        mp.undo()
    assert refitted[0] == "missing_scatterer" and a.name == "channel_gain"
    (v,) = run.vetoes
    assert v["name"] == "missing_scatterer" and v["gain_floor"][1] == 10.0
    assert 0 < v["gain_floor"][0] < 10.0
    assert "needs 10.000 nats" in _veto_reason(v)
    assert [c.effect.name for c in run.model.components] == ["channel_gain"]


def test_22_a_noise_model_must_claim_scatter_that_is_new_in_every_chirp():
    """Phase noise on every chirp (independent draws) and a power amplifier's
    droop over the frame (the Tx gain sagging 1.5 dB exponentially from
    chirp to chirp, the outside effect of the suite) both leave
    chirp-to-chirp scatter at the targets that a phase-noise skirt fits.
    The droop's repeats from one chirp to the next: its lag-1 chirp
    correlation is far above white noise's, and the candidate is not
    acceptable; the real phase noise's is within the white range (truth:
    the planted processes; white noise alone: |rho| < 3 / sqrt(n))."""
    from test_effects_sensor import _phase_noise_draws

    from sionna_mmir.effects.library.phase_noise import PhaseNoise
    from sionna_mmir.residual.ranking import chirp_memory, memory_stats, rank_candidates

    radar = RadarConfig.awr1843(num_chirps=16, num_samples=64)
    ctx = EffectContext(radar)
    clean = _clean(radar)
    F, T, R, Cn, N = ctx.shape
    folds = cv_folds(ctx.shape[:4], 3)
    noise = _noise(clean.shape, 3e-3, 31)
    # white noise alone: the bias of the chirp mean is taken out
    n = F * T * R * (Cn - 1)
    stats = [memory_stats(_noise(clean.shape, 1.0, 32), np.ones(N), ~t) for t in folds]
    memory, limit = chirp_memory(stats)
    assert memory < 2 / np.sqrt(n) and limit == pytest.approx(0.3 + 3 / np.sqrt(n))

    def scored(meas):
        m = EffectModel(ctx, meas, clean)
        m.fit(trainable=[])
        (c,) = rank_candidates(m, [PhaseNoise()], folds)
        return c

    phi = _phase_noise_draws(np.random.default_rng(33), (F, T, 1, Cn), N, -35.0, 2.0)
    jitter = scored(clean * np.exp(1j * phi) + noise)
    k = np.arange(Cn) / (Cn - 1)
    sag = 10 ** (-1.5 * (1 - np.exp(-k / 0.3)) / (1 - np.exp(-1 / 0.3)) / 20)
    droop = scored(clean * sag[None, None, None, :, None] + noise)
    assert jitter.gain > 100 and droop.gain > 100, (jitter, droop)
    assert jitter.chirp_memory < 0.3 < jitter.memory_limit < droop.chirp_memory, (jitter, droop)


def test_22b_chirp_memory_of_white_noise_is_unbiased():
    """Over many white series the lag-1 statistic's mean is 0 to within its
    spread: the mean removal's ``-1 / (C - 1)`` is taken out exactly (truth:
    ``E[D_{c+1} conj(D_c)] / E|D_c|^2 = -1 / (C - 1)`` for white noise),
    for 4 and 16 chirp loops; a ramp over the chirps gives nearly 1."""
    from sionna_mmir.residual.ranking import chirp_memory, memory_stats

    rng = np.random.default_rng(40)
    for C in (4, 16):
        shape = (1, 200, 50, C, 8)
        z = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / np.sqrt(2)
        stats = memory_stats(z, np.ones(8), np.ones(shape[:4], bool))
        n = 200 * 50 * (C - 1)
        lag = stats["lag"] / (200 * 50 * (C - 1))
        power = stats["power"] / (200 * 50 * C)
        rho = lag / power + 1.0 / (C - 1)
        assert np.all(np.abs(rho) < 4 / np.sqrt(n)), (C, rho)
        assert chirp_memory([stats])[0] < 3 / np.sqrt(n)
    ramp = np.broadcast_to(np.linspace(-1, 1, 16)[None, None, None, :, None], (1, 4, 4, 16, 8))
    dc = np.eye(8)[0]                               # a constant over fast time: range bin 0
    assert chirp_memory([memory_stats(ramp + 0j, dc, np.ones((1, 4, 4, 16), bool))])[0] > 0.8


def test_23_only_effects_that_share_signal_with_the_newest_are_backfitted():
    """After a walker is adopted beside a static point the scene lacks, the
    point's part of the mean model is orthogonal to the walker's (its
    Doppler phases sum to ~0 over 16 chirps): re-initialising it would land
    it where it is, so it is not backfitted; a per-channel gain scales every
    part and couples with all (truth: the planted targets; the overlap is
    checked against the inner products computed here by hand)."""
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.residual.adoption import MIN_OVERLAP, _coupled

    radar = RadarConfig.awr1843(num_chirps=16, num_samples=64)
    clean = _clean(radar)
    static = synthesize_adc(radar, np.array([0.8]), np.array([2 * 2.6 / C]))[None]
    t = radar.chirp_start_times()[None, :, None, :, None]
    walker = synthesize_adc(radar, np.array([0.3]), np.array([2 * 3.1 / C]))[None] * np.exp(
        4j * np.pi * radar.start_frequency * 1.0 * t / C)
    y = clean + static + walker + _noise(clean.shape, 0.03, 4)
    m = EffectModel(EffectContext(radar), y, clean)
    point = m.add(MissingScatterer())
    m.fit(maxiter=150)
    mover = m.add(MovingScatterer())
    m.fit(maxiter=150)
    assert mover.effect.summary(mover.values, m.ctx)["velocity_m_s"][0] == pytest.approx(1.0,
                                                                                          abs=0.15)
    full = m.mean_variance_numpy()[0]

    def part(c):
        every = m.components
        m.components = [x for x in every if x is not c]
        try:
            return full - m.mean_variance_numpy()[0]
        finally:
            m.components = every

    a, b = part(point), part(mover)
    overlap = abs(np.vdot(a, b)) / np.sqrt(np.vdot(a, a).real * np.vdot(b, b).real)
    assert overlap < MIN_OVERLAP / 2, overlap
    assert _coupled(m, mover) == {id(mover)}
    gain = m.add(ChannelGain())
    gain.values = {"tx": gain.values["tx"] + 0.1, "rx": gain.values["rx"]}
    assert _coupled(m, gain) == {id(c) for c in m.components}

