"""Cells of the evidence tables: one fit (or one transfer render) per call, cached.

The scripts ``comparisons/run_cross_truth.py``, ``run_transfer.py`` and
``run_ablations.py`` are loops over these cells; each cell runs in its own
interpreter (:func:`run_cell`: Dr.Jit has segfaulted in long facet fits) and
writes its result as JSON (+ latents and RA maps as ``.npz``) under
``<cache>/cells``, so a rerun only computes what is missing.

Settings shared by every cell (the benchmark runner's,
``comparisons/run_benchmark_scenes.py``):

* scaffold: ``lidarize_scene`` at 50k triangles, ``prepare_scaffold``
  (denoised, planes snapped, auto shading), nominal ITU materials;
* fit: min-max RA loss, Adam, ``lr`` 0.05 with a cosine schedule,
  :attr:`Budget.iterations` iterations, fit seed 0;
* mmIR: facet quadrature, paths 40 dB under the strongest dropped
  (:meth:`~sionna_mmir.paths.SolverOptions.benchmark`), element patterns
  :class:`~sionna_mmir.radio_devices.SharedShapePattern` (one ``cos^q``
  shape per array + per-element gain residuals), what :class:`Variant` says;
* Sionna RT: :class:`~sionna_mmir.baseline.SionnaBaseline` at depth 3 with
  :attr:`Budget.sionna_samples` rays per Tx element, per-object materials.
"""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time

import numpy as np

#: cache root (truths, scaffold-independent cells); ``$SIONNA_MMIR_EVIDENCE_CACHE``
DEFAULT_CACHE = os.environ.get("SIONNA_MMIR_EVIDENCE_CACHE", "/tmp/sionna_mmir_evidence")


@dataclasses.dataclass(frozen=True)
class Variant:
    """What an mmIR fit learns and renders.

    Parameters
    ----------
    name : str
        Label (file names, tables).
    learn : tuple of str
        :class:`~sionna_mmir.fit.MMIRModel` ``learn``.
    diffraction : bool
        Free-space diffraction in the fit's renders.
    max_depth : int
        Interactions per path.
    materials_per : {"vertex", "object"}
        Per-vertex or per-object (tied) materials.
    normals_smoothing : float
        Laplacian parameterisation of learned normals (lambda).
    materials_smoothing : float
        Laplacian parameterisation of the per-vertex material latents
        (lambda; 0: raw per-vertex latents).
    """

    name: str
    learn: tuple = ("materials", "beam")
    diffraction: bool = False
    max_depth: int = 3
    materials_per: str = "vertex"
    normals_smoothing: float = 500.0
    materials_smoothing: float = 0.0


#: the benchmark table's mmIR (materials and beams; normals and FSD off)
TABLE2 = Variant("table2")
#: the benchmark table's mmIR with spatially smooth materials (Laplacian, lambda 200)
TABLE2_SMOOTH = Variant("table2_smooth", materials_smoothing=200.0)
#: the paper's full model: materials, normals and beams learned, FSD on, depth 3
FULL = Variant("full", learn=("materials", "normals", "beam"), diffraction=True)
#: the ablations of the paper's supplement C.4, each one change from :data:`FULL`
ABLATIONS = (
    FULL,
    dataclasses.replace(FULL, name="no_beam", learn=("materials", "normals")),
    dataclasses.replace(FULL, name="no_normals", learn=("materials", "beam")),
    dataclasses.replace(FULL, name="no_fsd", diffraction=False),
    dataclasses.replace(FULL, name="single_bounce", max_depth=1),
    dataclasses.replace(FULL, name="per_object", materials_per="object"),
)
#: the same ablations from the full model without FSD (the base when a fit
#: with FSD does not fit in memory: the full model's FSD at depth 3 on the
#: parking lot peaked above 16 GB)
NO_FSD = dataclasses.replace(FULL, name="no_fsd", diffraction=False)
ABLATIONS_NO_FSD = (NO_FSD,) + tuple(
    dataclasses.replace(v, name=f"no_fsd+{v.name}", diffraction=False)
    for v in ABLATIONS if v.name not in ("full", "no_fsd"))
VARIANTS = {v.name: v for v in (TABLE2, TABLE2_SMOOTH) + ABLATIONS + ABLATIONS_NO_FSD}


@dataclasses.dataclass(frozen=True)
class Budget:
    """Fit budget, the same for every cell of a table."""

    iterations: int = 20
    lr: float = 0.05
    seed: int = 0
    sionna_samples: int = 30_000


def scaffold(spec) -> dict:
    """The LiDAR-like scaffold both fitters get (the benchmark runner's)."""
    from ..benchmark_scenes import lidarize_scene
    from ..scaffold import prepare_scaffold

    return prepare_scaffold(lidarize_scene(spec, seed=0, max_triangles=50_000))


def beam_patterns(radar, z: dict | None = None):
    """``(tx, rx)`` :class:`SharedShapePattern` for ``radar``: default shape, or the
    shape of fitted latents ``z`` (``beam.tx.log_q_az`` ...) with zero residuals."""
    from ..radio_devices import SharedShapePattern

    out = []
    for side, n in (("tx", radar.num_tx), ("rx", radar.num_rx)):
        if z is None or f"beam.{side}.log_q_az" not in z:
            out.append(SharedShapePattern(n_elements=n))
        else:
            qa, qe = (float(np.exp(np.ravel(z[f"beam.{side}.{k}"])[0]))
                      for k in ("log_q_az", "log_q_el"))
            out.append(SharedShapePattern(qa, qe, n_elements=n))
    return tuple(out)


def mmir_model(spec, meshes: dict, radar, variant: Variant, patterns=None):
    """An :class:`~sionna_mmir.fit.MMIRModel` of ``variant`` on ``meshes`` for ``radar``."""
    from ..fit import MMIRModel
    from ..paths.options import SolverOptions
    from ..scene import load_scene

    tx, rx = patterns or beam_patterns(radar)
    scene = load_scene(meshes, materials={k: spec.materials[k] for k in meshes}, radar=radar)
    opts = SolverOptions.benchmark(max_depth=variant.max_depth, diffraction=variant.diffraction)
    return MMIRModel(scene, radar, learn=variant.learn, tx_pattern=tx, rx_pattern=rx,
                     solver_options=opts, normals_smoothing=variant.normals_smoothing,
                     materials_smoothing=variant.materials_smoothing,
                     materials_per=variant.materials_per)


def sionna_model(spec, meshes: dict, radar, budget: Budget):
    """The Sionna RT baseline as a fittable model (:class:`~sionna_mmir.fit.SionnaModel`)."""
    from ..baseline import SionnaBaseline
    from ..fit import SionnaModel

    mats = {k: spec.materials[k] for k in meshes}
    return SionnaModel(SionnaBaseline(meshes, mats, radar, max_depth=3,
                                      samples_per_src=budget.sionna_samples))


def cell_stem(cache_dir, kind: str, truth: str, scene: str, model: str, budget: Budget) -> str:
    """Path stem of one cell's cached result (``.json`` / ``.npz``); the truth goes
    by its :func:`~sionna_mmir.compare.truths.cache_label`."""
    from .truths import cache_label

    return os.path.join(os.fspath(cache_dir), "cells",
                        f"{kind}_{cache_label(truth)}_{scene}_{model}_it{budget.iterations}")


def _save(stem: str, result: dict, arrays: dict) -> dict:
    os.makedirs(os.path.dirname(stem), exist_ok=True)
    np.savez(stem + ".npz", **arrays)
    with open(stem + ".json.part", "w") as f:
        json.dump(result, f, indent=1, default=float)
    os.replace(stem + ".json.part", stem + ".json")
    return result


def load_cell(stem: str):
    """``(result dict, arrays)`` of a cached cell, or ``(None, None)``."""
    if not os.path.exists(stem + ".json"):
        return None, None
    with open(stem + ".json") as f:
        result = json.load(f)
    with np.load(stem + ".npz") as a:
        arrays = {k: a[k] for k in a.files}
    return result, arrays


def fit_cell(truth: str, scene: str, model: str, budget: Budget, cache_dir=DEFAULT_CACHE) -> dict:
    """Fit ``model`` (``"sionna"`` or a :data:`VARIANTS` name) to ``truth``'s cascade
    capture of ``scene``; cached.  Returns the result dict (metrics before /
    after, loss history, seconds per iteration, wall time)."""
    from ..benchmark_scenes import build_scene
    from .harness import run_side, target_ra
    from .truths import cached_truth

    stem = cell_stem(cache_dir, "fit", truth, scene, model, budget)
    done, _ = load_cell(stem)
    if done is not None:
        return done
    t0 = time.perf_counter()
    spec = build_scene(scene, seed=0)
    cap = cached_truth(cache_dir, truth, spec, "cascade")
    meshes = scaffold(spec)
    m = (sionna_model(spec, meshes, cap.radar, budget) if model == "sionna"
         else mmir_model(spec, meshes, cap.radar, VARIANTS[model]))
    ra_ref = target_ra(cap.frames, cap.radar)
    side = run_side(model, m, ra_ref, cap.frames[0], iterations=budget.iterations,
                    lr=budget.lr, seed=budget.seed, progress=False)
    result = {"kind": "fit", "truth": truth, "scene": scene, "model": model,
              "budget": dataclasses.asdict(budget), "before": side.metrics_before,
              "after": side.metrics_after, "history": np.asarray(side.history).tolist(),
              "s_per_it": side.seconds_per_it, "wall_s": time.perf_counter() - t0}
    arrays = {"ra_after": side.ra_after, "ra_ref": ra_ref,
              **{f"z:{k}": np.asarray(v) for k, v in side.extra["latents"].items()}}
    return _save(stem, result, arrays)


def fitted_latents(truth: str, scene: str, model: str, budget: Budget,
                   cache_dir=DEFAULT_CACHE) -> dict:
    """The latents of a cached (or newly run) :func:`fit_cell`."""
    stem = cell_stem(cache_dir, "fit", truth, scene, model, budget)
    _, arrays = load_cell(stem)
    if arrays is None:
        fit_cell(truth, scene, model, budget, cache_dir)
        _, arrays = load_cell(stem)
    return {k[2:]: v for k, v in arrays.items() if k.startswith("z:")}


def _transfer_mmir(spec, meshes, radar, variant, z_fit):
    """``(model, latents before, latents after)`` of mmIR on ``radar``: the cascade
    fit's scene latents (materials, normals) and beam shape, no gain residuals."""
    before = mmir_model(spec, meshes, radar, variant)
    z0 = before.latents()
    after = mmir_model(spec, meshes, radar, variant, patterns=beam_patterns(radar, z_fit))
    z1 = after.latents()
    scene_keys = [k for k in z1 if not k.startswith("beam.")]
    z1.update({k: np.asarray(z_fit[k]) for k in scene_keys})
    return before, z0, after, z1


def transfer_cell(truth: str, scene: str, model: str, budget: Budget,
                  cache_dir=DEFAULT_CACHE) -> dict:
    """Render the AWR1843 with the scene fitted on the cascade (frozen) and with
    the nominal one; metrics against ``truth``'s AWR1843 capture.  Cached."""
    from ..benchmark_scenes import build_scene
    from .harness import evaluate, target_ra
    from .truths import cached_truth

    stem = cell_stem(cache_dir, "transfer", truth, scene, model, budget)
    done, _ = load_cell(stem)
    if done is not None:
        return done
    t0 = time.perf_counter()
    spec = build_scene(scene, seed=0)
    z_fit = fitted_latents(truth, scene, model, budget, cache_dir)
    cap = cached_truth(cache_dir, truth, spec, "awr1843")
    meshes = scaffold(spec)
    ra_ref = target_ra(cap.frames, cap.radar)
    if model == "sionna":
        m0 = m1 = sionna_model(spec, meshes, cap.radar, budget)
        z0, z1 = m0.latents(), {k: np.asarray(v) for k, v in z_fit.items()}
    else:
        m0, z0, m1, z1 = _transfer_mmir(spec, meshes, cap.radar, VARIANTS[model], z_fit)
    before, ra0 = evaluate(m0, z0, ra_ref, cap.frames[0])
    after, ra1 = evaluate(m1, z1, ra_ref, cap.frames[0])
    result = {"kind": "transfer", "truth": truth, "scene": scene, "model": model,
              "budget": dataclasses.asdict(budget), "before": before, "after": after,
              "radar": cap.radar.name, "radar_position": cap.radar.position.tolist(),
              "radar_orientation": list(cap.radar.orientation),
              "wall_s": time.perf_counter() - t0}
    return _save(stem, result, {"ra_before": ra0, "ra_after": ra1, "ra_ref": ra_ref})


def truth_cell(truth: str, scene: str, sensor: str, cache_dir=DEFAULT_CACHE) -> dict:
    """Render (or read) one cached truth; returns its metadata."""
    from ..benchmark_scenes import build_scene
    from .truths import cached_truth

    cap = cached_truth(cache_dir, truth, build_scene(scene, seed=0), sensor)
    return dict(cap.metadata)


def run_cell(kind: str, truth: str, scene: str, model: str, budget: Budget = Budget(),
             cache_dir=DEFAULT_CACHE, retries: int = 1) -> dict:
    """Run one cell (``fit`` / ``transfer`` / ``truth``; for ``truth`` ``model`` is
    the sensor) in a fresh interpreter, retried ``retries`` times if the
    interpreter dies.  Returns its result dict."""
    cmd = [sys.executable, "-m", "sionna_mmir.compare.evidence", kind, truth, scene, model,
           "--iterations", str(budget.iterations), "--cache", os.fspath(cache_dir)]
    for attempt in range(retries + 1):
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode == 0:
            return json.loads(out.stdout.strip().splitlines()[-1])
        print(f"{kind} {truth} {scene} {model}: exit {out.returncode} (attempt {attempt + 1})\n"
              f"{out.stderr[-2000:]}", file=sys.stderr, flush=True)
    raise RuntimeError(f"cell {kind} {truth} {scene} {model} failed {retries + 1} times")


def _main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(description="one evidence cell (used by run_cell)")
    p.add_argument("kind", choices=["fit", "transfer", "truth"])
    p.add_argument("truth")
    p.add_argument("scene")
    p.add_argument("model", help="'sionna', a Variant name, or the sensor for 'truth'")
    p.add_argument("--iterations", type=int, default=Budget.iterations)
    p.add_argument("--cache", default=DEFAULT_CACHE)
    a = p.parse_args(argv)
    budget = Budget(iterations=a.iterations)
    if a.kind == "truth":
        res = truth_cell(a.truth, a.scene, a.model, a.cache)
    else:
        fn = fit_cell if a.kind == "fit" else transfer_cell
        res = fn(a.truth, a.scene, a.model, budget, a.cache)
    print(json.dumps(res, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(_main())
