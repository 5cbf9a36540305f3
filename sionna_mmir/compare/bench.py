"""Seconds per fit iteration, mmIR vs Sionna RT, same scene, same run.

One fit iteration = render with a fresh sample set, RA processing, min-max
RA loss, backward pass -- for mmIR (gradients to what it learns: per-vertex
materials, normals, beam parameters) and for the Sionna RT baseline
(gradients to its per-object material scalars), on the same LiDAR-like
benchmark scene, radar and ray budget (mmIR ``rays`` from the array centre;
Sionna ``rays`` samples per source).  Warm-up first, then ``repeat``
interleaved rounds (one iteration of each side per round); the ratio (median
of the per-round ratios) is the figure to read on a noisy machine.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..errors import ConfigError
from ..paths.options import SolverOptions
from ..scaffold.prepare import ScaffoldOptions


@dataclasses.dataclass
class BenchRequest:
    """One speed comparison.

    Parameters
    ----------
    scene : str
        Benchmark scene name (:data:`sionna_mmir.benchmark_scenes.SCENES`).
    solver : SolverOptions
        mmIR solver settings (``num_rays`` is also Sionna's samples per
        source unless ``sionna_samples`` is given).
    scaffold : ScaffoldOptions
        Repair of the LiDAR mesh before both models get it.
    learn : tuple of str
        What mmIR learns.
    """

    scene: str = "hallway"
    solver: SolverOptions = dataclasses.field(default_factory=lambda: SolverOptions.fit(
        num_rays=10_000))
    scaffold: ScaffoldOptions = dataclasses.field(default_factory=ScaffoldOptions.none)
    learn: tuple = ("materials", "beam")
    sionna_depth: int = 3
    sionna_samples: int | None = None
    repeat: int = 3
    max_triangles: int = 50_000


def one_iteration(model, target, seed) -> float:
    """Seconds of one render + loss + backward of ``model``."""
    import drjit as dr

    from ..processing.drjit_ra import ra_loss_from_adc

    z = model.latents()
    t0 = time.perf_counter()
    adc, handles = model.render(z, seed=seed)
    loss = ra_loss_from_adc(adc, model.radar, target)
    dr.backward(loss)
    for h in handles.values():
        dr.eval(dr.grad(h))
    return time.perf_counter() - t0


def time_interleaved(models, target, repeat):
    """Median seconds per iteration of each model and the median per-round ratio.

    Two warm-up iterations each: the second iteration compiles kernels of its
    own (with an empty Dr.Jit kernel cache Sionna RT's first two iterations
    on a 3000-triangle hallway took 14.0 and 9.5 s, the later ones
    0.6-0.7 s).  Then ``repeat`` rounds that time one iteration of every
    model in turn, so load changes on a shared machine hit both sides alike.
    """
    for seed in (98, 99):
        for m in models:
            one_iteration(m, target, seed)
    rounds = [[one_iteration(m, target, 100 + r) for m in models] for r in range(repeat)]
    t = np.asarray(rounds)
    return np.median(t, axis=0), float(np.median(t[:, 0] / t[:, 1]))


def _check(req: BenchRequest):
    from ..benchmark_scenes import SCENES
    from ..fit.models import LEARNABLE

    if req.scene not in SCENES:
        raise ConfigError(f"unknown scene {req.scene!r}; choose from {sorted(SCENES)}")
    bad = sorted(set(req.learn) - set(LEARNABLE))
    if not req.learn or bad:
        raise ConfigError(f"learn: cannot learn {bad or 'nothing'}; choose from {LEARNABLE}")
    samples = req.solver.num_rays if req.sionna_samples is None else req.sionna_samples
    for opt, val in (("repeat", req.repeat), ("sionna_depth", req.sionna_depth),
                     ("sionna_samples", samples), ("max_triangles", req.max_triangles)):
        if val < 1:
            raise ConfigError(f"{opt} must be >= 1, got {val}")
    return samples


def run_bench(req: BenchRequest) -> dict:
    """Time both models on the request's scene; returns the figures."""
    from ..baseline import SionnaBaseline
    from ..benchmark_scenes import build_scene, lidarize_scene
    from ..fit import MMIRModel, SionnaModel
    from ..paths.render import to_numpy
    from ..processing.imaging import range_azimuth
    from ..scaffold import prepare_scaffold
    from ..scene import load_scene
    from .ground_truth import scene_radar

    samples = _check(req)
    spec = build_scene(req.scene, seed=0)
    radar = scene_radar(spec)
    lidar = lidarize_scene(spec, seed=0, max_triangles=req.max_triangles)
    lidar = prepare_scaffold(lidar, req.scaffold)
    mats = {k: spec.materials[k] for k in lidar}
    mm = MMIRModel(load_scene(lidar, materials=mats, radar=radar), learn=tuple(req.learn),
                   solver_options=req.solver)
    adc, _ = mm.render(mm.latents(), seed=7)
    target = range_azimuth(to_numpy(adc), radar)[0] ** 0.8      # any fixed, different map
    sio = SionnaModel(SionnaBaseline(lidar, mats, radar, max_depth=req.sionna_depth,
                                     samples_per_src=samples))
    out = {"scene": req.scene, "triangles": int(sum(len(m.faces) for m in lidar.values())),
           "rays": req.solver.num_rays, "sionna_samples": samples, "radar": radar.name,
           "rounds": req.repeat, "solver": req.solver.describe(),
           "scaffold": dataclasses.asdict(req.scaffold), "sionna_depth": req.sionna_depth,
           "learn": list(req.learn)}
    med, ratio = time_interleaved((mm, sio), target, req.repeat)
    out["mmir_s_per_it"], out["sionna_s_per_it"] = float(med[0]), float(med[1])
    out["ratio_mmir_over_sionna"] = ratio          # median of the per-round ratios
    return out


def bench_table(out: dict) -> str:
    """One Markdown table row (with header) of :func:`run_bench`'s figures."""
    s = out["solver"]
    return (f"| scene | triangles | rays / Sionna samples | mmIR sampling, depth | mmIR s/it | "
            f"Sionna RT s/it | ratio |\n|---|---|---|---|---|---|---|\n"
            f"| {out['scene']} | {out['triangles']} | {out['rays']} / {out['sionna_samples']} | "
            f"{s['sampling']}, {s['max_depth']} | {out['mmir_s_per_it']:.2f} | "
            f"{out['sionna_s_per_it']:.2f} | {out['ratio_mmir_over_sionna']:.2f} |")
