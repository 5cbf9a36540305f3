"""``sionna-mmir synth``: point targets -> an HDF5 capture (exact per-pair delays)."""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..radar.config import RadarConfig
from .args import FORMATTER, add_out, check_new


def add_parser(sub) -> None:
    p = sub.add_parser("synth", help="synthesise point targets into an HDF5 capture",
                       formatter_class=FORMATTER)
    p.add_argument("--radar", default="mmwcas", choices=list(RadarConfig.PRESETS),
                   help="radar preset")
    p.add_argument("--target", action="append", required=True, metavar="R,AZ[,EL[,V]]",
                   help="range [m], azimuth [deg], elevation [deg], radial velocity [m/s]; "
                        "repeatable")
    p.add_argument("--chirps", type=int, default=None,
                   help="chirp loops per frame (default: the preset's)")
    p.add_argument("--noise-db", type=float, default=None,
                   help="complex white noise power relative to a unit target [dB]")
    add_out(p, "output .h5 capture")
    p.set_defaults(run=run)


def parse_target(text: str) -> list:
    """``R,AZ[,EL[,V]]`` -> ``[R, AZ, EL, V]`` (finite, ``R > 0``)."""
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


def run(args) -> int:
    from ..captures.capture import Capture
    from ..fmcw.synthesize import synthesize_adc
    from ..fmcw.targets import point_target_paths

    check_new(args.out, args.overwrite)
    kw = {} if args.chirps is None else {"num_chirps": args.chirps}
    radar = RadarConfig.preset(args.radar, **kw)
    targets = [parse_target(t) for t in args.target]
    a, tau, rate = point_target_paths(radar, targets)
    moving = any(t[3] != 0 for t in targets)
    adc = synthesize_adc(radar, a, tau, rate if moving else None)
    if args.noise_db is not None:
        rng = np.random.default_rng(0)
        sigma = np.sqrt(10 ** (args.noise_db / 10) / 2)
        adc = adc + (sigma * (rng.normal(size=adc.shape) + 1j * rng.normal(size=adc.shape))
                     ).astype(np.complex64)
    meta = {"targets": targets, "noise_db": args.noise_db}
    Capture(adc, radar, meta, "synthetic").save(args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}")
    return 0
