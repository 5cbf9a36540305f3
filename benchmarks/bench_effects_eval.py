"""Effect-model benchmark: one loss-and-gradient evaluation of a joint refit.

The loop's joint refits and candidate fits beside a chirp-varying effect
(ego motion, a mover) evaluate the whole model on every chirp loop at every
L-BFGS-B step.  This times that evaluation (``EffectModel.loss`` and its
gradient in every parameter, as ``EffectModel.fit`` runs it) on a
cascade-sized capture, 12 Tx x 16 Rx x 16 chirps x 256 samples (or an
AWR1843's, 3 x 4 x 8 x 128), with nine
point-target objects as the per-object basis, their object gains, a pose
offset, a mover and ego motion, for:

* ``kept``: the package (a chirp-invariant basis kept ``[1, T, R, 1, N]``,
  the scene-side effects run once and their sum broadcast);
* ``full``: the reference twin, the same model with the basis held at
  ``[F, T, R, C, N]`` (every scene-side effect on every chirp loop).

Both in the same run on the same model; the NLL and gradients are compared.

Run:  python benchmarks/bench_effects_eval.py [--repeat 5] [--radar cascade|awr1843]
      [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from sionna_mmir import RadarConfig
from sionna_mmir.effects import EffectContext, EffectModel, ops
from sionna_mmir.effects.scene_basis import SceneBasis
from sionna_mmir.fmcw.synthesize import synthesize_adc
from sionna_mmir.radar.config import SPEED_OF_LIGHT


def _targets(rng, k=9):
    r = rng.uniform(2.0, 6.0, k)
    az = np.radians(rng.uniform(-50, 50, k))
    z = rng.uniform(-0.5, 0.5, k)
    return np.stack([r * np.cos(az), r * np.sin(az), z], axis=1)


def _adc(radar, points, gains):
    out = []
    for p, g in zip(points, gains):
        tau = (np.linalg.norm(p - radar.tx_positions, axis=1)[:, None]
               + np.linalg.norm(p - radar.rx_positions, axis=1)[None])[..., None] / SPEED_OF_LIGHT
        a = np.full(tau.shape, g / np.linalg.norm(p) ** 2, complex)
        out.append(synthesize_adc(radar, a, tau).astype(np.complex128))
    return np.stack(out)


RADARS = {"cascade": lambda: RadarConfig.mmwcas(num_chirps=16),
          "awr1843": lambda: RadarConfig.awr1843(num_chirps=8)}


def build(seed=0, radar="cascade"):
    """The benchmark's model: the radar (``RADARS``), nine objects, four effects."""
    from sionna_mmir.effects.library.ego_motion import EgoMotion
    from sionna_mmir.effects.library.moving_scatterer import MovingScatterer
    from sionna_mmir.effects.library.scene_mismatch import ObjectGain, PoseOffset

    rng = np.random.default_rng(seed)
    radar = RADARS[radar]()
    pts = _targets(rng)
    B = _adc(radar, pts, np.ones(len(pts)))
    centre = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
    d = pts - centre
    dist = np.linalg.norm(d, axis=1)
    e = np.sum(np.abs(B) ** 2, axis=(1, 2, 3, 4))
    basis = SceneBasis(names=[f"o{i}" for i in range(len(pts))], adc=B,
                       directions=d / dist[:, None], ranges=dist,
                       offsets_tx=radar.tx_positions - centre,
                       offsets_rx=radar.rx_positions - centre, rotation=np.eye(3),
                       shares=e / e.sum())
    y = np.tensordot(rng.uniform(0.5, 1.5, len(pts)), B, axes=1)
    y = y + 1e-3 * np.abs(y).max() * (rng.normal(size=y.shape) + 1j * rng.normal(size=y.shape))
    m = EffectModel(EffectContext(radar, basis=basis), y[None])
    for eff in (ObjectGain(), PoseOffset(), MovingScatterer(), EgoMotion()):
        m.add(eff)
    m.components[-1].values["velocity"] = np.array([0.5])
    return m


def full_twin(m):
    """The reference twin: ``m`` with its basis at full size."""
    twin = m.copy()
    k = twin.base_gain / twin.scale
    twin.basis_t = [ops.tensor(np.broadcast_to(b[None], twin.ctx.shape) * k)
                    for b in twin.ctx.basis.adc]
    return twin


def evaluate(model, repeat):
    """``(loss, gradient, [seconds per evaluation])`` of ``repeat`` evaluations."""
    dr = ops.dr
    keys = [(-1, k) for k in model.nuisance.specs] + \
        [(i, k) for i, c in enumerate(model.components) for k in c.specs]
    mask, n = model.mask_tensor(None)
    times = []
    with ops.single_thread(), model.held():
        for _ in range(repeat + 1):                 # the first one compiles the kernels
            t0 = time.perf_counter()
            tens = model._tensors(grad_keys=set(keys))
            loss = model.loss(tens, mask, n, None)
            dr.backward(loss)
            grads = [dr.grad(tens[k]) for k in keys]
            dr.eval(loss, *grads)
            g = np.concatenate([np.asarray(x, np.float64).ravel() for x in grads])
            times.append(time.perf_counter() - t0)
    return ops.item(loss), g, times[1:]


def run(repeat=5, seed=0, radar="cascade"):
    m = build(seed, radar)
    lk, gk, tk = evaluate(m, repeat)
    lf, gf, tf = evaluate(full_twin(m), repeat)
    return {"shape": list(m.ctx.shape), "objects": len(m.basis_t),
            "components": [c.effect.name for c in m.components],
            "kept_s": float(np.median(tk)), "full_s": float(np.median(tf)),
            "speedup": float(np.median(tf) / np.median(tk)),
            "loss_rel_diff": abs(lk - lf) / max(abs(lf), 1e-30),
            "grad_rel_diff": float(np.max(np.abs(gk - gf)) / max(np.max(np.abs(gf)), 1e-30))}


def to_markdown(res) -> str:
    return "\n".join([
        f"Capture {' x '.join(map(str, res['shape']))}, {res['objects']} objects, "
        f"components: {', '.join(res['components'])}; one thread (the fits' setting).", "",
        "| basis | s per loss + gradient (median) |", "|---|---|",
        f"| kept per chirp loop only where it differs (package) | {res['kept_s']:.3f} |",
        f"| full size (reference twin) | {res['full_s']:.3f} |", "",
        f"Speed-up {res['speedup']:.2f}x; NLL relative difference {res['loss_rel_diff']:.1e}, "
        f"largest gradient difference {res['grad_rel_diff']:.1e} of the largest gradient."])


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--radar", default="cascade", choices=sorted(RADARS))
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    res = run(a.repeat, radar=a.radar)
    print(to_markdown(res))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
