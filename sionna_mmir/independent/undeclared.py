"""Independent generator of realistic captures with planted (undeclared) effects.

A room with 2-4 corner reflectors, diffuse clutter and a cabinet is "measured"
by a TI cascade (ColoRadar's MMWCAS waveform, 12 x 16) or an AWR1843-class
single chip; one or two effects from the package's effects library (or from
outside it) are planted; the user gets the capture, a triangle mesh that only
approximates the clutter and the radar pose they believe, and the truth
records every drawn parameter.

Independence
------------
Nothing here is imported from :mod:`sionna_mmir.paths`, ``bsdf``, ``fmcw``,
``effects`` or ``residual``, nor from Mitsuba / Dr.Jit: the ADC is
synthesised from exact per-(Tx, Rx) geometry in plain NumPy
(:mod:`.undeclared_adc`), the scene and its scattering physics are written in
:mod:`.undeclared_scene`, the effects from the hardware's physics in
:mod:`.undeclared_effects`.  Only data containers are shared:
:class:`~sionna_mmir.radar.RadarConfig` (waveform, layout, pose),
:class:`~sionna_mmir.captures.Capture`, and the error type.  The captures
follow the package's sign convention (a target at range ``R`` at the positive
beat frequency ``2 R S / c``, ``exp(+j 2 pi (f0 + S t) tau)``).

Signal chain (in this order)::

    paths (scene, corners, specular walls, planted scatterers, coupling;
           RF delays, ramp error, LO phase noise, motion)       -> render
    x channel gain [T, R], x PA droop [T, chirp]                (RF chains)
    x counts scale;  + interference                             (antenna)
    x exp(j 2 pi df_chip t);  I/Q imbalance                     (mixer)
    IF high-pass: lfilter from the ramp start, at 4 f_s         (IF)
    + thermal noise (white at f_s, through the same I/Q errors and high-pass)
    + coloured noise                                            (IF amplifier)
    ADC window;  + DC;  clip;  optional rounding to integers    (ADC)

The signal is rendered from the ramp start (not only over the ADC window) so
the high-pass runs from its reset with zero state; with the IF filter
planted it is rendered at :data:`IF_OVERSAMPLING` ``f_s``, so that the
discrete filter (bilinear, corner pre-warped) follows the analog response
over the whole complex beat band ``[0, f_s)`` (two 700 kHz stages: within
0.03 dB and 2 deg near ``f_s``, less below), and then decimated.

Scale: the complex thermal noise has std :data:`NOISE_STD_COUNTS` ADC
counts; ``snr_db`` is the per-sample SNR of the strongest corner (its mean
power over channels), so the range-FFT SNR is ``snr_db + 10 log10(N)``.

Randomness: the scene, the noise and each effect draw from their own
streams of ``numpy.random.SeedSequence(seed)``, so cases with the same seed
and radar share the room, the clutter and the thermal noise; the difference
between a case and the clean control is the planted effect alone (apart
from clipping, which acts on everything).
"""
from __future__ import annotations

import dataclasses
import math
import zlib

import numpy as np

from ..captures.capture import Capture
from ..errors import ConfigError, InputValueError
from ..radar.config import RadarConfig
from . import undeclared_effects as fx
from .undeclared_adc import C0, Motion, RampError, elements, pair_terms, render, rotation
from .undeclared_io import write_coloradar_run
from .undeclared_scene import RADAR_POSITION, build_scene

__all__ = ["SuiteCase", "make_case", "suite", "iter_suite", "suite_kinds", "write_coloradar_run",
           "coloradar_cascade", "waveform_variant", "parse_kind", "case_name", "LIBRARY_EFFECTS",
           "OUTSIDE_EFFECTS", "SCENE_MISMATCH", "FULL_PAIRS", "FAST_KINDS", "NOISE_STD_COUNTS"]

#: Library effects that can be planted (names of :mod:`sionna_mmir.effects.library`).
LIBRARY_EFFECTS = ("missing_scatterer", "moving_scatterer", "multipath_ghost", "coupling",
                   "channel_gain", "delay_offset", "frequency_offset", "chirp_nonlinearity",
                   "ego_motion", "phase_noise", "if_filter", "noise_floor", "dc_offset",
                   "iq_imbalance", "adc_clipping")
#: Effects no library effect can mimic.
OUTSIDE_EFFECTS = ("outside:interference", "outside:tx_droop")
#: Scene-side mismatch (the mesh's nominal radar pose is off).
SCENE_MISMATCH = ("pose_offset",)
#: Complex std of the thermal noise [ADC counts].
NOISE_STD_COUNTS = 10.0
#: Oversampling of the analog IF simulation when the IF filter is planted.
IF_OVERSAMPLING = 4
#: Frame period of multi-frame captures [s].
FRAME_PERIOD_S = 0.1
#: farthest point of the nominal room from the radar [m] (a room of scale
#: ``s`` reaches ``s`` times that; ``make_case``'s ``room_scale``)
ROOM_REACH_M = 11.2

#: ColoRadar cascade ``waveform_cfg.txt`` (times repaired to seconds).
COLORADAR_CASCADE_WAVEFORM = dict(
    start_frequency=76999999488.0, slope=7.90000010527e13, sample_rate=8e6, num_samples=256,
    num_chirps=16, idle_time=4.99999987369e-06, adc_start_time=6e-6, ramp_end_time=4e-5)
#: ColoRadar cascade ``antenna_cfg.txt`` (file order), ``(azimuth, elevation)`` in
#: half-wavelengths at 76.8 GHz.
COLORADAR_CASCADE_TX = ((0, 0), (4, 0), (8, 0), (9, 1), (10, 4), (11, 6), (12, 0), (16, 0),
                        (20, 0), (24, 0), (28, 0), (32, 0))
COLORADAR_CASCADE_RX = tuple((a, 0) for a in (0, 1, 2, 3, 11, 12, 13, 14, 46, 47, 48, 49, 50,
                                              51, 52, 53))
#: ColoRadar single-chip (AWR1843) waveform, used for ``radar="awr1843"``.
COLORADAR_SINGLE_CHIP_WAVEFORM = dict(
    start_frequency=76999999488.0, slope=1.00000000377e14, sample_rate=10666000.0,
    idle_time=0.000110000000859, adc_start_time=7.00000009601e-06,
    ramp_end_time=1.99999994948e-05)


@dataclasses.dataclass
class SuiteCase:
    """One generated capture with what a user is given and the truth.

    Parameters
    ----------
    name : str
        case name (``"clean"``, ``"if_filter+coupling"``, ...)
    capture : Capture
        :class:`Capture`, complex64 ``[F, T, R, chirps,
        samples]`` in ADC counts, radar = ``radar_nominal``
    meshes : dict
        ``name -> trimesh.Trimesh`` in the scene frame [m]
    materials : dict
        ``name -> ITU material class`` (``"concrete"``, ...)
    radar_nominal : RadarConfig
        the :class:`RadarConfig` with the pose the user believes
    effects : tuple
        planted effects: library names, ``"pose_offset"``,
        ``"outside:..."``; ``()`` for the clean control
    truth : dict
        every drawn parameter (JSON-serialisable)
    seed : int
        the seed
    """

    name: str
    capture: Capture
    meshes: dict
    materials: dict
    radar_nominal: RadarConfig
    effects: tuple
    truth: dict
    seed: int


def _layout_positions(table, design_hz: float) -> np.ndarray:
    hw = C0 / (2.0 * design_hz)
    arr = np.asarray(table, float)
    return np.stack([np.zeros(len(arr)), arr[:, 0] * hw, arr[:, 1] * hw], axis=1)


def coloradar_cascade(num_chirps: int = 16, num_samples: int = 256) -> RadarConfig:
    """ColoRadar's MMWCAS cascade (12 x 16, file order, TDM Tx 0..11) at the nominal pose."""
    wf = dict(COLORADAR_CASCADE_WAVEFORM, num_chirps=num_chirps, num_samples=num_samples)
    return RadarConfig(**wf, tx_positions=_layout_positions(COLORADAR_CASCADE_TX, 76.8e9),
                       rx_positions=_layout_positions(COLORADAR_CASCADE_RX, 76.8e9),
                       tdm_order=tuple(range(12)), position=RADAR_POSITION,
                       name="coloradar_cascade", design_frequency=76.8e9)


def waveform_variant(radar="cascade", *, slope=None, sample_rate=None, num_samples=None,
                     num_chirps=None) -> RadarConfig:
    """One of the suite's radars with another waveform: the same array and
    start frequency, a chosen slope [Hz/s], ADC sample rate [Hz], samples per
    chirp and chirp loops (each ``None`` keeps the nominal value).  The ramp
    is lengthened when the ADC window would outlast it (a user's waveform of
    the same radar family, not the capture's).  Refused (InputValueError)
    when the room (11.2 m) is beyond its maximum range or the chirp leaves
    the band."""
    base = _radar(radar, num_chirps, None)
    over = {k: float(v) for k, v in (("slope", slope), ("sample_rate", sample_rate))
            if v is not None}
    if num_samples is not None:
        over["num_samples"] = _count("waveform_variant", "num_samples", num_samples)
    fs, n = over.get("sample_rate", base.sample_rate), over.get("num_samples", base.num_samples)
    adc_end = base.adc_start_time + n / fs
    if adc_end > base.ramp_end_time:
        over["ramp_end_time"] = adc_end * (1 + 1e-6)
    try:
        cfg = base.replace(**over)
    except ConfigError as e:
        raise InputValueError(f"waveform_variant: {e}") from None
    return _radar(cfg, None, None)


def _count(owner: str, name: str, v) -> int:
    """``v`` as a positive integer, else InputValueError naming ``owner`` and ``name``."""
    if isinstance(v, bool) or int(v) != v or int(v) < 1:
        raise InputValueError(f"{owner}: {name} must be a positive integer, got {v!r}")
    return int(v)


def _radar(radar, num_chirps, num_samples, room_scale: float = 1.0) -> RadarConfig:
    """The nominal radar for a ``radar`` argument (name or RadarConfig),
    checked to reach a room of scale ``room_scale`` (11.2 m each)."""
    over = {k: v for k, v in (("num_chirps", num_chirps), ("num_samples", num_samples))
            if v is not None}
    over = {k: _count("make_case", k, v) for k, v in over.items()}
    try:
        if isinstance(radar, RadarConfig):
            cfg = radar.replace(**over)
        elif isinstance(radar, str) and radar == "cascade":
            cfg = coloradar_cascade(over.get("num_chirps", 16), over.get("num_samples", 256))
        elif isinstance(radar, str) and radar == "awr1843":
            cfg = RadarConfig.awr1843(**dict(COLORADAR_SINGLE_CHIP_WAVEFORM,
                                             num_chirps=over.get("num_chirps", 8),
                                             num_samples=over.get("num_samples", 128)))
        else:
            raise InputValueError(f"make_case: radar must be 'cascade', 'awr1843' or a "
                                  f"RadarConfig, got {radar!r}")
        cfg = cfg.replace(position=RADAR_POSITION, orientation=np.zeros(3))
    except ConfigError as e:
        raise InputValueError(f"make_case: {e}") from None
    if cfg.slope <= 0:
        raise InputValueError(f"make_case: radar {cfg.name!r} has a falling chirp (slope "
                              f"{cfg.slope:g} Hz/s); the suite's scenes need a rising one")
    reach = ROOM_REACH_M * room_scale
    if cfg.max_range < reach + 0.8:
        raise InputValueError(
            f"make_case: the room reaches {reach:.1f} m but radar {cfg.name!r} has a maximum "
            f"range of {cfg.max_range:.1f} m (f_s c / 2 S); use a waveform with "
            f"f_s / S >= {2 * (reach + 0.8) / C0:.2g} s")
    return cfg


def parse_kind(kind) -> tuple:
    """Effects of a ``kind`` (name, tuple of names or ``"clean"``) in canonical order."""
    names = (kind,) if isinstance(kind, str) else kind
    if not isinstance(names, (tuple, list)) or not all(isinstance(n, str) for n in names):
        raise InputValueError(f"make_case: kind must be an effect name or a tuple of names, "
                              f"got {kind!r}")
    if tuple(names) == ("clean",):
        return ()
    known = LIBRARY_EFFECTS + SCENE_MISMATCH + OUTSIDE_EFFECTS
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise InputValueError(
            f"make_case: unknown kind {bad or kind!r}; choose 'clean', 'pose_offset', one of "
            f"the library effects {', '.join(LIBRARY_EFFECTS)}, one of "
            f"{', '.join(OUTSIDE_EFFECTS)}, or a tuple of these")
    if len(set(names)) != len(names):
        raise InputValueError(f"make_case: kind {kind!r} names an effect twice")
    return tuple(sorted(names, key=known.index))


def case_name(effects: tuple) -> str:
    """``"clean"`` or the effects joined by ``+``."""
    return "+".join(effects) if effects else "clean"


def _stream(seed: int, name: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(zlib.crc32(
        name.encode()),)))


class _Context:
    """Radar, scene, time grids and helpers shared by the cases of one (seed, radar)."""

    def __init__(self, radar: RadarConfig, seed: int, num_frames: int, num_clutter,
                 room_scale: float = 1.0):
        self.radar, self.seed, self.room_scale = radar, seed, float(room_scale)
        self.num_tx, self.num_rx = radar.num_tx, radar.num_rx
        cascade = self.num_tx % 3 == 0 and self.num_rx % 4 == 0 and \
            self.num_tx // 3 == self.num_rx // 4 > 1
        self.num_chips = self.num_tx // 3 if cascade else 1
        self.tx_chip = np.arange(self.num_tx) // 3 if cascade else np.zeros(self.num_tx, int)
        self.rx_chip = np.arange(self.num_rx) // 4 if cascade else np.zeros(self.num_rx, int)
        self.lam = C0 / radar.center_frequency
        self.radar_pos = np.asarray(radar.position, float)
        self.noise_std = NOISE_STD_COUNTS
        rng = _stream(seed, "scene")
        n_corners = int(rng.integers(2, 5))
        if num_clutter is None:
            num_clutter = 4000 if self.num_tx * self.num_rx > 16 else 1500
        self.scene = build_scene(rng, self.lam, n_corners, int(num_clutter), self.room_scale)
        fs = radar.sample_rate
        self.n_pre = int(math.floor(radar.adc_start_time * fs))
        self.t = radar.adc_start_time + (np.arange(radar.num_samples + self.n_pre)
                                         - self.n_pre) / fs
        starts = radar.chirp_start_times()
        self.chirp_times = (np.arange(num_frames)[:, None, None] * FRAME_PERIOD_S
                            + starts[None])
        corners = self.scene.corner_paths(self.lam, self.radar_pos)
        el = elements(radar, self.radar_pos, np.eye(3))
        _, amp, _ = pair_terms(corners, el, self.lam)
        rms = np.sqrt(np.mean(np.abs(amp) ** 2, axis=(0, 1)))
        self.strongest = int(np.argmax(rms))
        self.ref_amp = float(rms[self.strongest])
        self.cache = {}

    def grid(self, up: int = 1) -> np.ndarray:
        """Fast times [s] from the ramp start, ``up`` per ADC sample, ``[up (n_pre + N)]``.

        Every ``up``-th instant is an ADC-rate instant; the last ``N`` of those
        are the ADC window.
        """
        return self.t[0] + np.arange(up * self.t.size) / (up * self.radar.sample_rate)

    def random_point(self, rng, r_min, r_max, az_max_deg, z_range) -> np.ndarray:
        """A point at range ``r_min..r_max`` (times the room's scale) and
        ``|azimuth| <= az_max_deg`` inside the room."""
        b = self.scene.bounds
        lo, hi = np.array(b["cabinet_lo"]), np.array(b["cabinet_hi"])
        r_min, r_max = self.room_scale * r_min, self.room_scale * r_max
        for _ in range(10000):
            r, az = rng.uniform(r_min, r_max), np.radians(rng.uniform(-az_max_deg, az_max_deg))
            p = np.array([r * math.cos(az), r * math.sin(az), rng.uniform(*z_range)])
            p[:2] += self.radar_pos[:2]
            in_cab = np.all(p[:2] > lo[:2] - 0.4) and np.all(p[:2] < hi[:2] + 0.4)
            if (b["x_back"] + 0.4 < p[0] < b["x_far"] - 0.4 and not in_cab
                    and b["y_right"] + 0.4 < p[1] < b["y_left"] - 0.4):
                return p
        raise RuntimeError("no free point in the room")

    def clear_of_corners(self, p, dr: float, daz_deg: float) -> bool:
        """True when ``p`` is ``dr`` [m] in range or ``daz_deg`` in azimuth from every corner."""
        d = p - self.radar_pos
        for c in self.scene.corners:
            e = c.centre - self.radar_pos
            daz = abs(math.degrees(math.atan2(d[1], d[0]) - math.atan2(e[1], e[0])))
            if abs(np.linalg.norm(d) - np.linalg.norm(e)) < dr and daz < daz_deg:
                return False
        return True


_DRAW = {"channel_gain": fx.draw_channel_gain, "delay_offset": fx.draw_delay_offset,
         "frequency_offset": fx.draw_frequency_offset,
         "chirp_nonlinearity": fx.draw_chirp_nonlinearity, "phase_noise": fx.draw_phase_noise,
         "coupling": fx.draw_coupling, "missing_scatterer": fx.draw_missing_scatterer,
         "moving_scatterer": fx.draw_moving_scatterer,
         "multipath_ghost": fx.draw_multipath_ghost, "ego_motion": fx.draw_ego_motion,
         "pose_offset": fx.draw_pose_offset, "iq_imbalance": fx.draw_iq_imbalance,
         "if_filter": fx.draw_if_filter, "dc_offset": fx.draw_dc_offset,
         "adc_clipping": fx.draw_adc_clipping, "noise_floor": fx.draw_noise_floor,
         "outside:interference": fx.draw_interference, "outside:tx_droop": fx.draw_tx_droop}


def _motion(ctx: _Context, params: dict) -> Motion:
    """True radar pose (nominal, or offset) and velocity."""
    pos, rot = ctx.radar_pos.copy(), np.eye(3)
    if "pose_offset" in params:
        p = params["pose_offset"]
        pos = pos + np.asarray(p["position_offset_m"])
        rot = rotation(math.radians(p["yaw_offset_deg"]), 0.0, 0.0)
    vel = None
    if "ego_motion" in params:
        vel = params["ego_motion"]["speed_mps"] * rot[:, 0]
    return Motion(pos, rot, vel)


def _lo(ctx: _Context, params: dict):
    """One LO phase realisation per frame (phase_noise), else None."""
    if "phase_noise" not in params:
        return None
    r, dt = ctx.radar, 1.0 / (8 * ctx.radar.sample_rate)
    return [fx.lo_phase(params["phase_noise"], float(ct.min()) - 1e-6,
                        float(ct.max()) + r.ramp_end_time + 1e-6, dt) for ct in ctx.chirp_times]


def _scene_signal(ctx: _Context, params: dict, motion: Motion, up: int) -> np.ndarray:
    """Room, corners, specular walls (cached when static) plus planted paths and coupling.

    Rendered on the fast-time grid :meth:`_Context.grid` ``(up)``.
    """
    t = ctx.grid(up)
    ramp = None
    if "chirp_nonlinearity" in params:
        p = params["chirp_nonlinearity"]
        ramp = RampError(p["b2_hz"], p["b3_hz"], p["ramp_s"])
    dtau = fx.delay_array(params["delay_offset"]) if "delay_offset" in params else None
    lo = _lo(ctx, params)
    sc = ctx.scene
    groups = [sc.clutter, sc.corner_paths(ctx.lam, ctx.radar_pos)]
    groups += sc.mirror_paths(ctx.radar.center_frequency)
    key = (up, tuple(motion.position), tuple(motion.rot.ravel()), repr(params.get(
        "chirp_nonlinearity")), repr(params.get("delay_offset")))
    kw = dict(ramp=ramp, lo=lo, dtau=dtau)
    if motion.velocity is None and lo is None and key in ctx.cache:
        x = ctx.cache[key].copy()
    else:
        x = render(ctx.radar, groups, motion, t, ctx.chirp_times, **kw)
        if motion.velocity is None and lo is None:
            ctx.cache[key] = x.copy()
    extra = []
    if "missing_scatterer" in params:
        extra.append(fx.point_paths(params["missing_scatterer"], ctx.lam))
    if "moving_scatterer" in params:
        p = params["moving_scatterer"]
        extra.append(fx.point_paths(p, ctx.lam, velocity=p["velocity_mps"]))
    if "multipath_ghost" in params:
        p = params["multipath_ghost"]
        extra.append(fx.ghost_paths(p, sc.corners[p["corner"]], ctx.lam))
    if "coupling" in params:
        extra.append(fx.coupling_paths(params["coupling"], ctx))
    if extra:
        x += render(ctx.radar, extra, motion, t, ctx.chirp_times, **kw)
    return x


def _rf_and_mixer(ctx: _Context, params: dict, x, up: int, scale: float, motion: Motion,
                  info: dict):
    """Channel gain, droop, counts scale, interference, frequency offset, I/Q (grid ``up``)."""
    t = ctx.grid(up)
    if "channel_gain" in params:
        x *= fx.gain_array(params["channel_gain"])[None, :, :, None, None]
    if "outside:tx_droop" in params:
        rel = ctx.chirp_times - ctx.chirp_times.min(axis=(1, 2), keepdims=True)
        x *= fx.droop_gain(params["outside:tx_droop"], rel)[:, :, None, :, None]
    x *= scale
    if "outside:interference" in params:
        el = elements(ctx.radar, motion.position, motion.rot)
        burst, hits = fx.interference(params["outside:interference"], ctx, el, ctx.chirp_times,
                                      t, up)
        x += scale * burst
        info["interference_hit_chirps"] = np.argwhere(hits).tolist()
    if "frequency_offset" in params:
        df = np.asarray(params["frequency_offset"]["rx_chip_hz"])[ctx.rx_chip]
        x *= np.exp(2j * np.pi * df[None, None, :, None, None] * t)
    if "iq_imbalance" in params:
        x = fx.apply_iq_imbalance(x, params["iq_imbalance"])
    return x


def _thermal(ctx: _Context, params: dict) -> np.ndarray:
    """White receiver noise on the ADC-rate grid, through the mixer's I/Q and the IF high-pass."""
    shape = ctx.chirp_times.shape[:2] + (ctx.num_rx,) + ctx.chirp_times.shape[2:] + (ctx.t.size,)
    rng = _stream(ctx.seed, "thermal_noise")
    n = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) * (ctx.noise_std / math.sqrt(2))
    if "iq_imbalance" in params:
        n = fx.apply_iq_imbalance(n, params["iq_imbalance"])
    if "if_filter" in params:
        n = fx.apply_if_filter(n, params["if_filter"], ctx.radar.sample_rate)
    return n


def _if_and_adc(ctx: _Context, params: dict, x, up: int, quantize: bool, info: dict):
    """IF high-pass (at ``up`` f_s), thermal and coloured noise, ADC window, DC, clip, rounding."""
    if "if_filter" in params:
        x = fx.apply_if_filter(x, params["if_filter"], up * ctx.radar.sample_rate)
    x = x[..., ::up] + _thermal(ctx, params)
    if "noise_floor" in params:
        times = ctx.chirp_times[..., None] + ctx.t
        x = x + fx.coloured_noise(params["noise_floor"], ctx, times)
    x = x[..., ctx.n_pre:]
    if "dc_offset" in params:
        d = np.asarray(params["dc_offset"]["rx_counts"])
        x = x + (d[:, 0] + 1j * d[:, 1])[None, None, :, None, None]
    if "adc_clipping" in params:
        x, level = fx.apply_clipping(x, params["adc_clipping"]["fraction"])
        info["clip_level_counts"] = level
    if quantize:
        x = np.rint(x.real) + 1j * np.rint(x.imag)
    return x


def _check_snr(snr_db) -> float:
    try:
        v = float(snr_db)
    except (TypeError, ValueError):
        raise InputValueError(f"make_case: snr_db must be a number [dB], got {snr_db!r}") from None
    if not math.isfinite(v) or not -20.0 <= v <= 80.0:
        raise InputValueError(f"make_case: snr_db must be finite and within [-20, 80] dB "
                              f"(per-sample SNR of the strongest corner), got {snr_db!r}")
    return v


def _truth(ctx: _Context, params: dict, motion: Motion, snr_db: float, scale: float,
           info: dict) -> dict:
    """JSON-ready record of the scene, the true pose and every drawn parameter."""
    sc, lam = ctx.scene, ctx.lam
    clutter = sc.clutter
    yaw = params.get("pose_offset", {}).get("yaw_offset_deg", 0.0)
    return {
        "generator": "sionna_mmir.independent.undeclared", "version": 1,
        "radar_nominal": {"position_m": ctx.radar_pos.tolist(), "orientation_rad": [0.0] * 3},
        "radar_true": {"position_m": motion.position.tolist(),
                       "orientation_rad": [math.radians(yaw), 0.0, 0.0],
                       "velocity_mps": None if motion.velocity is None
                       else motion.velocity.tolist()},
        "snr_db": snr_db, "noise_std_counts": ctx.noise_std, "counts_per_path_unit": scale,
        "frame_period_s": FRAME_PERIOD_S, "room": sc.bounds,
        "corners": [c.to_dict(lam) for c in sc.corners], "strongest_corner": ctx.strongest,
        "clutter": {"positions_m": clutter.q_tx.round(5).tolist(),
                    "coef_m": fx._c(clutter.coef),
                    "material": [int(m) for m in sc.clutter_info["material"]],
                    "area_per_point_m2": sc.clutter_info["area_per_point_m2"]},
        "specular": [{"surface": o, "gamma": fx._c(m.gamma)} for o, m in zip(
            [r.name for r in sc.rects], sc.mirror_paths(ctx.radar.center_frequency))],
        "effects": params, "derived": info,
    }


def _build(ctx: _Context, effects: tuple, snr_db: float, quantize: bool) -> SuiteCase:
    params = {name: _DRAW[name](_stream(ctx.seed, name), ctx) for name in effects}
    motion = _motion(ctx, params)
    up = IF_OVERSAMPLING if "if_filter" in params else 1
    x = _scene_signal(ctx, params, motion, up)
    scale = ctx.noise_std * 10 ** (snr_db / 20) / ctx.ref_amp
    info = {}
    x = _rf_and_mixer(ctx, params, x, up, scale, motion, info)
    x = _if_and_adc(ctx, params, x, up, quantize, info)
    meta = {"frame_period": FRAME_PERIOD_S, "units": "adc_counts",
            "generator": "sionna_mmir.independent.undeclared"}
    cap = Capture(x.astype(np.complex64), ctx.radar, meta, source="synthetic")
    return SuiteCase(case_name(effects), cap, ctx.scene.meshes(), ctx.scene.materials(),
                     ctx.radar, effects, _truth(ctx, params, motion, snr_db, scale, info),
                     ctx.seed)


def make_case(kind, *, seed: int = 0, radar="cascade", num_chirps: int | None = None,
              num_samples: int | None = None, snr_db: float = 35.0, num_frames: int = 1,
              num_clutter: int | None = None, quantize: bool = False,
              room_scale: float = 1.0) -> SuiteCase:
    """Generate one case.

    Parameters
    ----------
    kind : str or tuple of str
        ``"clean"``, ``"pose_offset"``, a library effect name (see
        :data:`LIBRARY_EFFECTS`), ``"outside:interference"``,
        ``"outside:tx_droop"``, or a tuple of these.
    seed : int
        Seed of the scene, the noise and every effect draw.
    radar : {"cascade", "awr1843"} or RadarConfig
        ``"cascade"``: ColoRadar's MMWCAS (12 x 16, 16 chirps, 256 samples);
        ``"awr1843"``: 3 x 4 with ColoRadar's single-chip waveform (8 chirps,
        128 samples).  The pose is replaced by the nominal one.
    num_chirps, num_samples : int, optional
        Override the chirp loops per frame / samples per chirp.
    snr_db : float
        Per-sample SNR [dB] of the strongest corner, in [-20, 80].
    num_frames : int
        Frames ``F`` (``FRAME_PERIOD_S`` apart).
    num_clutter : int, optional
        Clutter points drawn (default 4000 for > 16 virtual channels, else 1500).
    quantize : bool
        Round the ADC to integer counts.
    room_scale : float
        Floor plan of the room stretched by this factor in [1, 4]: walls,
        corner and scatterer ranges (reflector edges by its square root);
        the radar must reach ``11.2 room_scale`` m.  2.5 makes a 25 m hall.

    Returns
    -------
    SuiteCase
        ``capture.frames`` complex64 ``[F, T, R, chirps, samples]`` [counts].

    Raises
    ------
    InputValueError
        Unknown kind, bad SNR, bad sizes or an unsuitable radar.
    """
    effects = parse_kind(kind)
    ctx, snr = _setup(seed, radar, num_chirps, num_samples, snr_db, num_frames, num_clutter,
                      room_scale)
    return _build(ctx, effects, snr, bool(quantize))


def _setup(seed, radar, num_chirps, num_samples, snr_db, num_frames, num_clutter,
           room_scale=1.0):
    """Validated ``(_Context, snr_db)``."""
    snr = _check_snr(snr_db)
    if isinstance(room_scale, bool) or not isinstance(room_scale, (int, float, np.number)) \
            or not 1.0 <= float(room_scale) <= 4.0:
        raise InputValueError(f"make_case: room_scale must be a number in [1, 4], "
                              f"got {room_scale!r}")
    for name, v in (("seed", seed), ("num_frames", num_frames)):
        low = 1 if name == "num_frames" else 0
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
            raise InputValueError(f"make_case: {name} must be a non-negative integer "
                                  f"(num_frames >= 1), got {v!r}")
    if num_clutter is not None and (isinstance(num_clutter, bool)
                                    or not isinstance(num_clutter, (int, np.integer))
                                    or num_clutter < 1):
        raise InputValueError(f"make_case: num_clutter must be a positive integer, "
                              f"got {num_clutter!r}")
    ctx = _Context(_radar(radar, num_chirps, num_samples, float(room_scale)), int(seed),
                   int(num_frames), num_clutter, float(room_scale))
    return ctx, snr


#: Pairs of the full suite (>= 8): effects that meet in real captures.
FULL_PAIRS = (("channel_gain", "iq_imbalance"), ("coupling", "if_filter"),
              ("chirp_nonlinearity", "dc_offset"), ("delay_offset", "frequency_offset"),
              ("missing_scatterer", "ego_motion"), ("phase_noise", "noise_floor"),
              ("multipath_ghost", "channel_gain"), ("moving_scatterer", "adc_clipping"),
              ("coupling", "adc_clipping"), ("delay_offset", "if_filter"))
#: Cases of the fast suite (AWR1843-class radar, 8 chirps, 128 samples).
FAST_KINDS = ("clean", ("channel_gain", "iq_imbalance"), ("coupling", "if_filter"),
              "ego_motion", "multipath_ghost", "pose_offset", "outside:interference",
              "outside:tx_droop")


def suite_kinds(subset: str = "full") -> list:
    """The kinds of :func:`suite` (``"fast"`` or ``"full"``)."""
    if subset == "fast":
        return list(FAST_KINDS)
    if subset == "full":
        return (["clean"] + list(LIBRARY_EFFECTS) + [p for p in FULL_PAIRS]
                + list(SCENE_MISMATCH) + list(OUTSIDE_EFFECTS))
    raise InputValueError(f"suite: subset must be 'fast' or 'full', got {subset!r}")


def iter_suite(subset: str = "full", seed: int = 0, **kw):
    """Generate the cases of :func:`suite` one at a time.

    Parameters and cases as :func:`suite`; yields :class:`SuiteCase` (the
    room, clutter and thermal noise are drawn once for all of them).
    """
    kinds = suite_kinds(subset)
    radar = "awr1843" if subset == "fast" else "cascade"
    bad = set(kw) - {"snr_db", "num_frames", "num_clutter", "quantize"}
    if bad:
        raise InputValueError(f"suite: unknown keyword(s) {sorted(bad)}")
    ctx, snr = _setup(seed, radar, None, None, kw.get("snr_db", 35.0), kw.get("num_frames", 1),
                      kw.get("num_clutter"))
    quantize = bool(kw.get("quantize", False))
    for kind in kinds:
        yield _build(ctx, parse_kind(kind), snr, quantize)


def suite(subset: str = "full", seed: int = 0, **kw) -> list:
    """Generate the suite of cases, all sharing one room, clutter and noise.

    Parameters
    ----------
    subset : {"full", "fast"}
        ``"full"``: ColoRadar's cascade (12 x 16, 16 chirps, 256 samples);
        the clean control, each library effect alone, :data:`FULL_PAIRS`, the
        pose offset and the two outside effects (29 cases, ~2 min).
        ``"fast"``: the :data:`FAST_KINDS` on the ``"awr1843"`` radar (8
        chirps, 128 samples; ~1-2 s).
    seed : int
        Seed of the room, the noise and every effect draw.
    **kw
        ``snr_db``, ``num_frames``, ``num_clutter``, ``quantize`` of
        :func:`make_case`.

    Returns
    -------
    list of SuiteCase
        In the order of :func:`suite_kinds`.
    """
    suite_kinds(subset)
    return list(iter_suite(subset, seed, **kw))
