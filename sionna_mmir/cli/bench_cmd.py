"""``sionna-mmir bench``: seconds per fit iteration, mmIR vs Sionna RT, same scene, same run.

One fit iteration = render with a fresh sample set, RA processing, min-max RA
loss, backward pass -- for mmIR (gradients to every per-vertex material,
normal and beam parameter) and for the Sionna RT baseline (gradients to its
per-object material scalars), on the same LiDAR-like benchmark scene, radar
and ray budget (mmIR ``rays`` from the array centre; Sionna ``rays`` samples
per source).  Warm-up first, then ``--repeat`` interleaved rounds (one iteration of
each side per round); the ratio (median of the per-round ratios) is the
figure to read on a noisy machine.
"""
from __future__ import annotations

import json
import time

import numpy as np


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help="seconds per fit iteration: mmIR vs Sionna RT, same run")
    p.add_argument("--scene", default="hallway", help="benchmark scene (sionna_mmir.scenes)")
    p.add_argument("--rays", type=int, default=10_000)
    p.add_argument("--depth", type=int, default=2, help="mmIR max depth")
    p.add_argument("--sionna-depth", type=int, default=3, help="Sionna RT max depth")
    p.add_argument("--sampling", default="random", choices=["random", "facets"],
                   help="mmIR path sampling (facets: the benchmark table's fits)")
    p.add_argument("--denoise", action="store_true",
                   help="denoise the LiDAR mesh first (as the benchmark table does)")
    p.add_argument("--shading", default="shared", choices=["shared", "flat", "auto"],
                   help="shading normals of the (denoised) mesh: shared vertices as scanned, "
                        "flat, or auto (sionna_mmir.scene.auto_shaded, the benchmark table's)")
    p.add_argument("--flat-shading", action="store_true", help="same as --shading flat")
    p.add_argument("--planes", action="store_true",
                   help="snap planar regions onto fitted planes after --denoise "
                        "(sionna_mmir.scene.snap_planes, as the benchmark table does)")
    p.add_argument("--sionna-samples", type=int, default=None,
                   help="Sionna samples per source (default: --rays)")
    p.add_argument("--min-rel-power", type=float, default=1e-6,
                   help="mmIR path pruning threshold (MMIRModel.min_rel_power)")
    p.add_argument("--learn", default="materials,beam",
                   help="what mmIR learns, comma-separated (default: the benchmark table's "
                        "fits, materials and beam patterns)")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--max-triangles", type=int, default=50_000, help="LiDAR mesh budget")
    p.add_argument("--json", default=None, help="write results here")


def _one_iteration(model, target, seed):
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


def _time_interleaved(models, target, repeat):
    """Median seconds per iteration of each model and the median per-round ratio.

    One warm-up iteration each (kernel compilation), then ``repeat`` rounds
    that time one iteration of every model in turn, so load changes on a
    shared machine hit both sides alike.
    """
    for m in models:
        _one_iteration(m, target, 99)
    rounds = [[_one_iteration(m, target, 100 + r) for m in models] for r in range(repeat)]
    t = np.asarray(rounds)
    return np.median(t, axis=0), float(np.median(t[:, 0] / t[:, 1]))


def cmd_bench(args) -> int:
    from ..baseline import SionnaBaseline
    from ..compare.ground_truth import scene_radar
    from ..errors import ConfigError
    from ..fit import MMIRModel, SionnaModel
    from ..processing.imaging import range_azimuth
    from ..paths.render import to_numpy
    from ..scene import load_scene, prepare_scaffold
    from ..scenes import SCENES, build_scene, lidarize_scene

    from ..fit.models import LEARNABLE

    if args.scene not in SCENES:
        raise ConfigError(f"unknown scene {args.scene!r}; choose from {sorted(SCENES)}")
    learn = tuple(x for x in args.learn.split(",") if x)
    bad = sorted(set(learn) - set(LEARNABLE))
    if not learn or bad:
        raise ConfigError(f"--learn: cannot learn {bad or 'nothing'}; choose from {LEARNABLE}")
    samples = args.rays if args.sionna_samples is None else args.sionna_samples
    for opt, val in (("--rays", args.rays), ("--repeat", args.repeat), ("--depth", args.depth),
                     ("--sionna-depth", args.sionna_depth), ("--sionna-samples", samples)):
        if val < 1:
            raise ConfigError(f"{opt} must be >= 1, got {val}")
    spec = build_scene(args.scene, seed=0)
    radar = scene_radar(spec)
    lidar = lidarize_scene(spec, seed=0, max_triangles=args.max_triangles)
    shading = "flat" if args.flat_shading else args.shading
    lidar = prepare_scaffold(lidar, denoise=args.denoise, planes=args.planes, shading=shading)
    mats = {k: spec.materials[k] for k in lidar}
    mm = MMIRModel(load_scene(lidar, materials=mats, radar=radar), learn=learn,
                   solver_options=dict(num_rays=args.rays, max_depth=args.depth,
                                       sampling=args.sampling),
                   min_rel_power=args.min_rel_power)
    adc, _ = mm.render(mm.latents(), seed=7)
    target = range_azimuth(to_numpy(adc), radar)[0] ** 0.8      # any fixed, different map
    sio = SionnaModel(SionnaBaseline(lidar, mats, radar, max_depth=args.sionna_depth,
                                     samples_per_src=samples))
    out = {"scene": args.scene, "triangles": int(sum(len(m.faces) for m in lidar.values())),
           "rays": args.rays, "sionna_samples": samples,
           "min_rel_power": args.min_rel_power, "radar": radar.name, "rounds": args.repeat,
           "sampling": args.sampling, "depth": args.depth, "sionna_depth": args.sionna_depth,
           "denoise": bool(args.denoise), "planes": bool(args.planes), "shading": shading,
           "learn": list(learn)}
    med, ratio = _time_interleaved((mm, sio), target, args.repeat)
    out["mmir_s_per_it"], out["sionna_s_per_it"] = float(med[0]), float(med[1])
    out["ratio_mmir_over_sionna"] = ratio          # median of the per-round ratios
    print(f"| scene | triangles | rays / Sionna samples | mmIR sampling, depth | mmIR s/it | "
          f"Sionna RT s/it | ratio |\n"
          f"|---|---|---|---|---|---|---|\n"
          f"| {out['scene']} | {out['triangles']} | {out['rays']} / {samples} | "
          f"{args.sampling}, {args.depth} "
          f"| {out['mmir_s_per_it']:.2f} | "
          f"{out['sionna_s_per_it']:.2f} | {out['ratio_mmir_over_sionna']:.2f} |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0
