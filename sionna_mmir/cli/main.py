"""``sionna-mmir`` command line.

Every command has ``--help``.  Bad input (missing or malformed files, wrong
shapes, NaN) prints ``error: <what and where>`` on stderr and exits with
status 2; outputs are written atomically, so a failing command leaves no
partial file.  Existing outputs are never overwritten without ``--overwrite``.
"""
from __future__ import annotations

import argparse
import sys

from . import bench_cmd, fit_cmd, occupancy_cmd, render_cmd, residual_cmd

EXIT_BAD_INPUT = 2


def _add_capture_args(p):
    p.add_argument("capture", help="capture: TI .mat, DCA1000 .bin, ColoRadar run folder or "
                                    "frame_N.bin, OpenRadar .npy, or sionna_mmir HDF5")
    p.add_argument("--frame", type=int, default=None, help="frame index (multi-frame captures)")
    p.add_argument("--calib-dir", default=None, help="ColoRadar calib folder")
    p.add_argument("--sensor", default="cascade", choices=["cascade", "single_chip"],
                   help="ColoRadar sensor")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sionna-mmir",
        description="Differentiable mmWave FMCW radar rendering on Sionna RT.")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="run the main job (signal-chain demo on the measured "
                                    "corner capture, or an embedded synthetic one)")
    p.add_argument("--capture", default=None, help="capture to use (default: "
                   "../shared/data/measured/mmwcas_corner/corner_4m7_slope79.mat if found)")
    p.add_argument("--out", default="sionna_mmir_demo", help="report folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report")
    p.add_argument("--iterations", type=int, default=6,
                   help="fit iterations per model in the inverse-rendering stage (0: skip)")

    p = sub.add_parser("info", help="summarise a capture (radar, shapes, strongest return)")
    _add_capture_args(p)

    p = sub.add_parser("convert", help="convert a capture to the sionna_mmir HDF5 format")
    _add_capture_args(p)
    p.add_argument("output", help="output .h5 path")
    p.add_argument("--overwrite", action="store_true")

    p = sub.add_parser("ra", help="range-azimuth picture(s) of a capture")
    _add_capture_args(p)
    p.add_argument("--out", required=True, help="output PNG")
    p.add_argument("--frames", type=int, default=1, help="number of frames to average "
                   "non-coherently from --frame on (progress bar)")
    p.add_argument("--cartesian", action="store_true", help="x/y picture instead of range/angle")
    p.add_argument("--doppler", default="mean", choices=["mean", "noncoherent"])
    p.add_argument("--overwrite", action="store_true")

    p = sub.add_parser("synth", help="synthesise point targets into an HDF5 capture")
    p.add_argument("--radar", default="mmwcas", choices=["mmwcas", "awr1843", "dense"])
    p.add_argument("--target", action="append", required=True, metavar="R,AZ[,EL[,V]]",
                   help="range [m], azimuth [deg], elevation [deg], radial velocity [m/s]; "
                        "repeatable")
    p.add_argument("--chirps", type=int, default=None)
    p.add_argument("--noise-db", type=float, default=None,
                   help="complex white noise power relative to a unit target [dB]")
    p.add_argument("--output", required=True)
    p.add_argument("--overwrite", action="store_true")

    render_cmd.add_parser(sub)
    fit_cmd.add_parsers(sub)
    bench_cmd.add_parser(sub)
    residual_cmd.add_parser(sub)
    occupancy_cmd.add_parser(sub)
    return parser


def main(argv=None) -> int:
    from ..errors import SionnaMMIRError
    from ..utils.backend import BackendError
    from . import commands

    parser = build_parser()
    args = parser.parse_args(argv)
    handlers = {"demo": commands.cmd_demo, "info": commands.cmd_info,
                "convert": commands.cmd_convert, "ra": commands.cmd_ra,
                "synth": commands.cmd_synth, "render": render_cmd.cmd_render, "fit": fit_cmd.cmd_fit,
                "compare": fit_cmd.cmd_compare, "bench": bench_cmd.cmd_bench,
                "residual": residual_cmd.cmd_residual, "occupancy": occupancy_cmd.cmd_occupancy}
    try:
        return int(handlers[args.command](args) or 0)
    except (SionnaMMIRError, FileNotFoundError, FileExistsError, IsADirectoryError,
            IndexError, BackendError) as e:
        msg = str(e)
        if isinstance(e, FileNotFoundError) and e.filename and e.filename not in msg:
            msg = f"{e.filename}: {msg}"
        print(f"error: {msg}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
