"""How much of the chirp-to-chirp scatter lies along the LO phase-noise direction.

    .venv/bin/python comparisons/phase_noise_coherence.py [--cases clean phase_noise]
        [--radar cascade|awr1843] [--seed 0]

Truth: the planted effects of :mod:`sionna_mmir.independent.undeclared`
(16 chirps).  Every Rx of one transmit slot (frame, Tx, chirp) sees the same
LO realisation, so the phase noise adds ``(e(t) / S) dx/dt`` to all of them
with one real frequency error ``e(t)`` per slot and sample.  The statistic is
the package's screen, :func:`sionna_mmir.residual.screening.coherent_excess`:
the deviation from the chirp mean projected on the real direction of that
error, in units of white noise (1 for independent noise).  Prints one row
per case.
"""
from __future__ import annotations

import argparse

import numpy as np

from sionna_mmir.effects import EffectContext
from sionna_mmir.independent.undeclared import make_case
from sionna_mmir.residual.screening import coherent_excess


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["clean", "phase_noise"])
    ap.add_argument("--radar", choices=("cascade", "awr1843"), default="cascade")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    print("| case | excess along the common frequency error / white noise |\n|---|---|")
    for kind in args.cases:
        case = make_case(tuple(kind.split("+")), seed=args.seed, radar=args.radar, num_chirps=16)
        y = np.asarray(case.capture.frames, complex)
        ctx = EffectContext(case.capture.radar)
        print(f"| {kind} | {coherent_excess(y, ctx):.2f} |", flush=True)


if __name__ == "__main__":
    main()
