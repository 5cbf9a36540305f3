"""``sionna-mmir`` command line.

Every command has ``--help`` (defaults shown).  Bad input (missing or
malformed files, wrong shapes, NaN, impossible settings) prints
``error: <path>: <problem>`` on stderr and exits with status 2; outputs are
written atomically, so a failing command leaves no partial file, and
existing outputs are never overwritten without ``--overwrite``.  Each
command lives in a module of its own that parses its arguments and calls
the library.
"""
from __future__ import annotations

import argparse
import sys

from . import (bench, convert, dataset, demo, fit, info, loop, occupancy, ra, render,
               residual, synth)
from .boundary import EXIT_BAD_INPUT, error_boundary

#: command modules in the order ``--help`` lists them
COMMANDS = (demo, info, convert, ra, synth, render, fit, bench, residual, loop, dataset,
            occupancy)

__all__ = ["EXIT_BAD_INPUT", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="sionna-mmir",
        description="Differentiable mmWave FMCW radar rendering on Sionna RT.")
    parser.add_argument("--version", action="version", version=f"sionna-mmir {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.add_parser(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return error_boundary(args.run, args)


if __name__ == "__main__":
    sys.exit(main())
