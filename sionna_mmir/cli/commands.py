"""Implementations of the ``sionna-mmir`` sub-commands (see :mod:`.main`)."""
from __future__ import annotations

import json
import os
import pathlib

import numpy as np

from ..errors import InputValueError


def _load(args):
    from ..captures.loader import load_capture

    return load_capture(args.capture, frame=args.frame, calib_dir=args.calib_dir,
                        sensor=args.sensor)


def _check_new(path, overwrite):
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{path} exists; pass --overwrite to replace it")


def strongest_return(ra, ranges, az, r_min, r_max):
    """``(range [m], azimuth [rad], value)`` of the RA maximum within ``[r_min, r_max]``."""
    sel = (ranges >= r_min) & (ranges <= r_max)
    if not sel.any():
        raise InputValueError(f"no range bins between {r_min} and {r_max} m")
    sub = ra[sel]
    i, j = np.unravel_index(np.argmax(sub), sub.shape)
    return float(ranges[sel][i]), float(az[j]), float(sub[i, j])


def cmd_info(args) -> int:
    from ..processing.imaging import range_azimuth

    cap = _load(args)
    r = cap.radar
    ra, ranges, az = range_azimuth(cap.adc, r)
    r_peak, az_peak, _ = strongest_return(ra, ranges, az, 0.5, ranges[-1])
    print(f"source        {cap.source}")
    print(f"radar         {r.name}: {r.num_tx} tx x {r.num_rx} rx, {r.num_chirps} chirps x "
          f"{r.num_samples} samples")
    print(f"waveform      f0 {r.start_frequency / 1e9:.4f} GHz, slope {r.slope / 1e12:.3f} MHz/us, "
          f"fs {r.sample_rate / 1e6:.3f} Msps")
    print(f"range         resolution {r.range_resolution * 100:.2f} cm, max {r.max_range:.2f} m")
    print(f"frames        {cap.num_frames}")
    print(f"strongest     {r_peak:.3f} m, {np.degrees(az_peak):+.1f} deg (beyond 0.5 m)")
    return 0


def cmd_convert(args) -> int:
    _check_new(args.output, args.overwrite)
    cap = _load(args)
    cap.save(args.output, overwrite=args.overwrite)
    print(f"wrote {args.output} ({cap.num_frames} frame(s), {cap.radar.adc_shape})")
    return 0


def cmd_ra(args) -> int:
    from tqdm import tqdm

    from ..captures.loader import load_capture
    from ..plotting import save_ra_panels
    from ..processing.imaging import range_azimuth

    _check_new(args.out, args.overwrite)
    cap = load_capture(args.capture, calib_dir=args.calib_dir, sensor=args.sensor)
    first = args.frame or 0
    last = min(cap.num_frames, first + max(1, args.frames))
    if first >= cap.num_frames:
        raise IndexError(f"{args.capture}: frame {first} requested, capture has {cap.num_frames}")
    acc = None
    for f in tqdm(range(first, last), desc="RA frames", unit="frame", disable=last - first < 2):
        ra, ranges, az = range_azimuth(cap.frames[f], cap.radar, doppler=args.doppler)
        acc = ra if acc is None else acc + ra
    save_ra_panels({f"{pathlib.Path(args.capture).name} frames {first}-{last - 1}": acc},
                   ranges, az, args.out, cartesian=args.cartesian)
    print(f"wrote {args.out}")
    return 0


def _parse_target(text):
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputValueError(f"--target {text!r}: expected numbers R,AZ[,EL[,V]]") from None
    if not 2 <= len(vals) <= 4 or not np.all(np.isfinite(vals)):
        raise InputValueError(f"--target {text!r}: expected 2 to 4 finite numbers R,AZ[,EL[,V]]")
    vals += [0.0] * (4 - len(vals))
    if vals[0] <= 0:
        raise InputValueError(f"--target {text!r}: range must be positive")
    return vals


def point_target_paths(radar, targets, origin=None):
    """Exact per-pair delays and ``1/R^2`` amplitudes for point targets.

    ``targets``: iterable of ``(range_m, azimuth_deg, elevation_deg, v_m_s)``
    measured from ``origin`` (radar frame, default the radar origin; pass the
    virtual aperture's phase centre to place targets where the angle FFT
    sees them).  Returns ``a [tx, rx, P]``, ``tau`` [s], ``tau_rate``.
    """
    origin = np.zeros(3) if origin is None else np.asarray(origin, float)
    from ..radar.config import SPEED_OF_LIGHT as C

    tx, rx = radar.tx_positions, radar.rx_positions
    a, tau, rate = [], [], []
    for R, az, el, v in targets:
        az, el = np.radians(az), np.radians(el)
        u = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        x = origin + R * u
        d = np.linalg.norm(x - tx, axis=1)[:, None] + np.linalg.norm(x - rx, axis=1)[None, :]
        tau.append(d / C)
        rate.append(np.full(d.shape, 2 * v / C))
        a.append(np.ones(d.shape, complex) / (R * R))
    return np.stack(a, -1), np.stack(tau, -1), np.stack(rate, -1)


def named_radar(name: str, chirps: int | None = None, **kw):
    """``RadarConfig`` by CLI name (``mmwcas`` | ``awr1843`` | ``dense``)."""
    from ..radar.config import RadarConfig

    if chirps is not None:
        kw["num_chirps"] = chirps
    return {"mmwcas": RadarConfig.mmwcas, "awr1843": RadarConfig.awr1843,
            "dense": RadarConfig.dense}[name](**kw)


def cmd_synth(args) -> int:
    from ..captures.capture import Capture
    from ..fmcw.synthesize import synthesize_adc

    _check_new(args.output, args.overwrite)
    radar = named_radar(args.radar, args.chirps)
    targets = [_parse_target(t) for t in args.target]
    a, tau, rate = point_target_paths(radar, targets)
    moving = any(t[3] != 0 for t in targets)
    adc = synthesize_adc(radar, a, tau, rate if moving else None)
    if args.noise_db is not None:
        rng = np.random.default_rng(0)
        sigma = np.sqrt(10 ** (args.noise_db / 10) / 2)
        adc = adc + (sigma * (rng.normal(size=adc.shape) + 1j * rng.normal(size=adc.shape))
                     ).astype(np.complex64)
    meta = {"targets": targets, "noise_db": args.noise_db}
    Capture(adc, radar, meta, "synthetic").save(args.output, overwrite=args.overwrite)
    print(f"wrote {args.output}")
    return 0


def cmd_demo(args) -> int:
    from .demo import run_demo

    summary = run_demo(capture=args.capture, out=args.out, overwrite=args.overwrite,
                       fit_iterations=args.iterations)
    short = {k: v for k, v in summary.items() if k != "fit"}
    short["fit"] = {k: {"ra_correlation_before": v["metrics_before"]["ra_correlation"],
                        "ra_correlation_after": v["metrics_after"]["ra_correlation"],
                        "seconds_per_iteration": v["seconds_per_iteration"]}
                    for k, v in summary.get("fit", {}).items()}
    print(json.dumps(short, indent=1, default=float))
    return 0
