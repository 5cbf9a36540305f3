"""How much of the chirp-to-chirp scatter lies along the LO phase-noise direction.

    .venv/bin/python comparisons/phase_noise_coherence.py [--cases clean phase_noise] [--seed 0]

Truth: the planted effects of :mod:`sionna_mmir.independent.undeclared`
(cascade, 16 chirps).  Every Rx of one transmit slot (frame, Tx, chirp)
sees the same LO realisation, so the phase noise adds ``(e(t) / S) dx/dt``
to all of them with one frequency error ``e(t)`` per slot and sample.  Per
slot and sample the deviation from the chirp mean, ``d[r]``, is projected
on ``g[r]``, the spectral fast-time derivative of the chirp-mean signal over
the Rx; ``|g^H d|^2 / |g|^2`` is one white-floor variance on average for
independent noise (the deviation is the package's
:func:`~sionna_mmir.effects.library._sensor_common.chirp_deviation`, scaled
to keep white noise's power) and more where a shared latent pushes the
scatter along ``g``.  The floor is taken
from the median of ``|d|^2`` (exponential: ``median = s^2 ln 2``).  Prints
the ratio of the mean projected energy to that floor per case.
"""
from __future__ import annotations

import argparse

import numpy as np

from sionna_mmir.effects.library._sensor_common import chirp_deviation
from sionna_mmir.independent.undeclared import make_case


def coherent_excess(y: np.ndarray) -> float:
    """Mean ``|g^H d|^2 / |g|^2`` over slots and samples, in white-floor units.

    ``y`` complex ``[F, T, R, C, N]`` (``C >= 2``); ``d`` the chirp deviation, ``g`` the
    fast-time derivative of ``mean_C(y)`` (unitary DFT, bins in cycles per
    sample).
    """
    mean = y.mean(axis=3, keepdims=True)
    d = chirp_deviation(y)
    f = np.fft.fftfreq(y.shape[-1])
    g = np.fft.ifft(2j * np.pi * f * np.fft.fft(mean, axis=-1), axis=-1)       # [F, T, R, 1, N]
    floor = np.median(np.abs(d) ** 2) / np.log(2)
    proj = np.abs(np.sum(np.conj(g) * d, axis=2)) ** 2                          # [F, T, C, N]
    norm = np.maximum(np.sum(np.abs(g) ** 2, axis=2), 1e-300)                   # [F, T, 1, N]
    return float(np.mean(proj / norm) / floor)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["clean", "phase_noise"])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    print("| case | projected scatter / white floor |\n|---|---|")
    for kind in args.cases:
        case = make_case(kind, seed=args.seed, radar="cascade", num_chirps=16)
        print(f"| {kind} | {coherent_excess(np.asarray(case.capture.frames, complex)):.2f} |",
              flush=True)


if __name__ == "__main__":
    main()
