"""``sionna-mmir calibrate``: fit a radar unit's sensor profile from captures of it.

The work is :func:`sionna_mmir.effects.sensor_calibration.calibrate_files`
(per-channel gains and delays, Tx -> Rx leakage taps, fitted jointly with
each capture's point-target scene); the profile is an HDF5 file that
``fit``, ``compare``, ``render``, ``demo`` and ``loop`` take as
``--sensor-profile``.  This module only parses the command line.
"""
from __future__ import annotations

import json
import os

from .args import FORMATTER, add_out, add_waveform, waveform


def add_parser(sub) -> None:
    p = sub.add_parser("calibrate", help="fit a radar unit's sensor profile (channel gains, "
                                         "delays, Tx->Rx leakage) from captures of it",
                       formatter_class=FORMATTER)
    p.add_argument("captures", nargs="+", help="captures of one radar unit (any readable "
                                               "format), each with a dominant target")
    add_out(p, "output profile (.h5)")
    add_waveform(p)
    p.add_argument("--calib-dir", default=None, help="ColoRadar calib folder")
    p.add_argument("--sensor", default="cascade", choices=["cascade", "single_chip"],
                   help="ColoRadar sensor")
    p.add_argument("--rounds", type=int, default=4, help="alternations of delays, gains, leakage")
    p.add_argument("--leak-max", type=float, default=0.35,
                   help="farthest range the leakage taps reach [m]")
    p.add_argument("--min-range", type=float, default=1.0,
                   help="nearest range the calibration target is searched at [m]")
    p.set_defaults(run=run)


def run(args) -> int:
    from ..effects.sensor_calibration import calibrate_files
    from .args import positive

    positive(args.rounds, "--rounds")
    if not args.leak_max > 0 or not args.min_range > 0:
        from ..errors import ConfigError

        raise ConfigError("--leak-max and --min-range must be positive numbers of metres")
    profile = calibrate_files(args.captures, args.out, overwrite=args.overwrite,
                              waveform=waveform(args), calib_dir=args.calib_dir,
                              sensor=args.sensor, rounds=args.rounds, leak_max=args.leak_max,
                              r_min=args.min_range)
    print(json.dumps({os.path.basename(k): v for k, v in profile.quality.items()}, indent=1))
    print(f"wrote {args.out}: {profile.radar} {profile.num_tx} Tx x {profile.num_rx} Rx, "
          f"{len(profile.sources)} capture(s), format version {profile.format_version}")
    return 0
