"""``sionna-mmir synth``: point targets -> an HDF5 capture (exact per-pair delays)."""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..radar.config import RadarConfig
from .args import FORMATTER, add_out, noise_db, speed

#: working memory of a synthesis, in units of the output ADC's complex64 bytes
#: (the ADC, the synthesis' per-chirp phases and the noise draws)
WORK_FACTOR = 4


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
    """``R,AZ[,EL[,V]]`` -> ``[R, AZ, EL, V]`` (finite, ``R > 0``, ``|V| < c``)."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputValueError(f"--target {text!r}: expected numbers R,AZ[,EL[,V]]") from None
    if not 2 <= len(vals) <= 4 or not np.all(np.isfinite(vals)):
        raise InputValueError(f"--target {text!r}: expected 2 to 4 finite numbers R,AZ[,EL[,V]]")
    vals += [0.0] * (4 - len(vals))
    if vals[0] <= 0:
        raise InputValueError(f"--target {text!r}: range must be positive")
    speed(vals[3], f"--target {text!r}")
    return vals


def check_size(radar: RadarConfig, flag: str) -> None:
    """Refuse a synthesis whose working memory exceeds the machine's (before allocating)."""
    from ..utils.memory import array_bytes, check_memory, format_bytes

    shape = radar.adc_shape
    adc = array_bytes(shape, np.dtype(np.complex64).itemsize)
    check_memory(WORK_FACTOR * adc, f"{flag}: the ADC of {' x '.join(map(str, shape))} "
                                    f"[tx, rx, chirp, sample] ({format_bytes(adc)} as complex64)")


def add_noise(adc: np.ndarray, level_db: float, seed: int = 0) -> np.ndarray:
    """``adc`` plus complex white noise of power ``level_db`` [dB re. 1], in place."""
    rng = np.random.default_rng(seed)
    sigma = float(np.sqrt(10 ** (level_db / 10) / 2))     # a float keeps the draws float32
    adc.real += sigma * rng.standard_normal(adc.shape, dtype=np.float32)
    adc.imag += sigma * rng.standard_normal(adc.shape, dtype=np.float32)
    return adc


def run(args) -> int:
    from ..captures.capture import Capture
    from ..fmcw.synthesize import synthesize_adc
    from ..fmcw.targets import point_target_paths

    kw = {} if args.chirps is None else {"num_chirps": args.chirps}
    radar = RadarConfig.preset(args.radar, **kw)
    targets = [parse_target(t) for t in args.target]
    noise_db(args.noise_db)
    check_size(radar, f"--radar {args.radar} --chirps {radar.num_chirps}")
    a, tau, rate = point_target_paths(radar, targets)
    moving = any(t[3] != 0 for t in targets)
    adc = synthesize_adc(radar, a, tau, rate if moving else None)
    if args.noise_db is not None:
        adc = add_noise(adc, args.noise_db)
    meta = {"targets": targets, "noise_db": args.noise_db}
    Capture(adc, radar, meta, "synthetic").save(args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}")
    return 0
