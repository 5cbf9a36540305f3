"""``sionna-mmir`` command line.

Every command has ``--help`` (defaults shown).  Bad input (missing or
malformed files, wrong shapes, NaN, impossible settings, outputs that
cannot be written, requests larger than the machine) prints
``error: <path>: <problem>`` on stderr and exits with status 2; a bug
prints ``error: internal error: ...`` and exits with status 1 (see
:mod:`sionna_mmir.cli.boundary`).  ``--out`` is checked before the work
starts and a report folder is locked while it is written
(:func:`~sionna_mmir.cli.args.output_guard`); outputs are written
atomically, so a failing command leaves no partial file, and existing
outputs are never overwritten without ``--overwrite``.  Each command lives
in a module of its own that parses its arguments and calls the library.
"""
from __future__ import annotations

import argparse
import sys

from . import (bench, convert, dataset, demo, fit, info, loop, occupancy, ra, render,
               residual, synth)
from .args import output_guard
from .boundary import EXIT_BAD_INPUT, EXIT_INTERNAL, error_boundary

#: command modules in the order ``--help`` lists them
COMMANDS = (demo, info, convert, ra, synth, render, fit, bench, residual, loop, dataset,
            occupancy)

__all__ = ["EXIT_BAD_INPUT", "EXIT_INTERNAL", "build_parser", "main"]


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


def _guarded(args) -> int:
    with output_guard(args):
        return args.run(args)


def main(argv=None) -> int:
    """Run the command line ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    for stream in (sys.stdout, sys.stderr):     # paths that are not valid UTF-8 print escaped
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    args = build_parser().parse_args(argv)
    return error_boundary(_guarded, args)


if __name__ == "__main__":
    sys.exit(main())
