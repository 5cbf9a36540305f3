"""How exactly the ego-motion effect moves a room it did not render.

    .venv/bin/python comparisons/ego_motion_room.py [--chirps 16 8] [--seed 0]

Truth: :mod:`sionna_mmir.independent.undeclared` (no code shared with the
effects library).  Its cascade room (corners, clutter on the floor, walls
and ceiling, a cabinet) is generated twice with the same seed and noise, the
radar at rest (``clean``) and moving along boresight at its drawn speed
(``ego_motion``), at 80 dB SNR so the noise does not hide the model error.
:class:`~sionna_mmir.effects.library.ego_motion.EgoMotion` is applied to the
capture at rest at the true velocity; printed is the error ``|y - E(x)|^2``
as a share of the moving capture's energy [dB], for the effect as shipped,
with its elevation estimate switched off, and with no space-time atoms
(every range bin moved with its strongest direction); the static capture's
own distance to the moving one for scale; and the thermal noise of the
suite's default 35 dB SNR capture on the same scale.
"""
from __future__ import annotations

import argparse

import numpy as np

from sionna_mmir.effects import EffectContext, ops
from sionna_mmir.effects.library import ego_motion as em
from sionna_mmir.independent.undeclared import NOISE_STD_COUNTS, make_case


def _share_db(err, ref) -> float:
    return float(10 * np.log10(np.sum(np.abs(err) ** 2) / np.sum(np.abs(ref) ** 2)))


def _moved(effect, x, v, ctx) -> np.ndarray:
    p = {"velocity": ops.tensor(np.array([v]))}
    return ops.to_numpy(effect.apply(ops.tensor(x), p, ctx))


def rows(num_chirps: int, seed: int) -> dict:
    """Error shares [dB] of the variants for one chirp count."""
    rest = make_case("clean", seed=seed, radar="cascade", num_chirps=num_chirps, snr_db=80)
    moving = make_case("ego_motion", seed=seed, radar="cascade", num_chirps=num_chirps, snr_db=80)
    x = rest.capture.frames.astype(np.complex128)
    y = moving.capture.frames.astype(np.complex128)
    ctx = EffectContext(rest.capture.radar)
    v = float(moving.truth["radar_true"]["velocity_mps"][0])
    out = {"velocity_m_s": v, "static": _share_db(y - x, y),
           "effect": _share_db(y - _moved(em.EgoMotion(), x, v, ctx), y),
           "per_bin_only": _share_db(y - _moved(em.EgoMotion(max_directions=0), x, v, ctx), y)}
    flat = em.elevation_sines
    try:
        em.elevation_sines = lambda Y, c, s_y, step=0.01: np.zeros_like(np.asarray(s_y, float))
        em._GEOMETRY_CACHE.clear()
        out["no_elevation"] = _share_db(y - _moved(em.EgoMotion(), x, v, ctx), y)
    finally:
        em.elevation_sines = flat
        em._GEOMETRY_CACHE.clear()
    nominal = make_case("ego_motion", seed=seed, radar="cascade", num_chirps=num_chirps)
    f = nominal.capture.frames
    out["noise_at_35_db"] = float(10 * np.log10(NOISE_STD_COUNTS ** 2 * f.size
                                                / np.sum(np.abs(f) ** 2)))
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--chirps", type=int, nargs="+", default=[16, 8])
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    print("| chirps | v [m/s] | effect | no elevation | per bin only | at rest | noise (35 dB SNR) |")
    print("|---|---|---|---|---|---|---|")
    for c in a.chirps:
        r = rows(c, a.seed)
        print(f"| {c} | {r['velocity_m_s']:.3f} | {r['effect']:.1f} | {r['no_elevation']:.1f} "
              f"| {r['per_bin_only']:.1f} | {r['static']:+.1f} | {r['noise_at_35_db']:.1f} |",
              flush=True)


if __name__ == "__main__":
    main()
