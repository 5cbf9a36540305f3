"""How far can a fit on the LiDAR scaffold get?  RA correlation against the
benchmark ground truth of renders with the *true* materials on each geometry.

    .venv/bin/python comparisons/scaffold_ceiling.py [--scenes hallway,lab]

For each benchmark scene: the ground truth of ``run_benchmark_scenes.py``
(facet quadrature, clean mesh, true materials, depth 3, diffraction, noise),
then mmIR renders (facet quadrature, no fit) of

=================  ==========================================================
clean              the clean mesh, true materials (depth 3): the renderer's
                   own agreement with the truth
scan, noise-free   the LiDAR-like scan with its range / tangential noise off
                   (holes, shadows, tessellation only), true materials
scan               the LiDAR-like scan the fitters get, true materials
scan, denoised     that scan after ``scaffold.denoise_meshes``, true materials
denoised, nominal  the same with the nominal ITU materials (a fit's start)
denoised, auto-    the denoised scan shaded per object (``scaffold.auto_shaded``;
shaded             no plane snapping), true materials
scaffold           the benchmark table's scaffold: ``scaffold.prepare_scaffold``
                   (denoised, planes snapped, auto-shaded), true materials
=================  ==========================================================

Writes ``scaffold_ceiling.md`` / ``.csv`` beside this script.  A fit that
beats "scan, denoised" makes up for geometry with materials / normals.
"""
from __future__ import annotations

import argparse
import csv
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROWS = ("clean", "scan, noise-free", "scan", "scan, denoised", "denoised, nominal",
        "denoised, auto-shaded", "scaffold")


def _corr(spec, meshes, radar, ra_ref, true, depth):
    import mitsuba as mi

    from sionna_mmir.metrics import pearson
    from sionna_mmir.paths import render, to_numpy
    from sionna_mmir.processing.imaging import range_azimuth
    from sionna_mmir.scene import load_scene
    from sionna_mmir.benchmark_scenes import true_materials

    scene = load_scene(meshes, materials={k: spec.materials[k] for k in meshes}, radar=radar)
    if true:
        truth = true_materials(spec, seed=0, objects=meshes)
        for name, obj in scene.mesh_objects.items():
            obj.vertex_materials = mi.TensorXf(truth[name].astype(np.float32))
    adc = to_numpy(render(scene, max_depth=depth, sampling="facets", seed=1))
    return pearson(ra_ref, range_azimuth(adc, radar)[0])


def main(argv=None) -> int:
    import sionna_mmir  # noqa: F401
    from sionna_mmir.compare.ground_truth import render_ground_truth
    from sionna_mmir.compare.harness import target_ra
    from sionna_mmir.scaffold import auto_shaded, denoise_meshes, prepare_scaffold
    from sionna_mmir.benchmark_scenes import SCENES, build_scene, lidarize_scene

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--depth", type=int, default=3)
    p.add_argument("--gt-max-edge", type=float, default=0.08)
    p.add_argument("--lidar-max-triangles", type=int, default=50_000)
    p.add_argument("--out", default=HERE)
    args = p.parse_args(argv)
    table = {}
    for name in args.scenes.split(","):
        spec = build_scene(name, seed=0)
        cap = render_ground_truth(spec, seed=0, max_edge=args.gt_max_edge, sampling="facets")
        radar, ra_ref = cap.radar, target_ra(cap.frames, cap.radar)
        scan = lidarize_scene(spec, seed=0, max_triangles=args.lidar_max_triangles)
        quiet = lidarize_scene(spec, seed=0, max_triangles=args.lidar_max_triangles,
                               range_noise_std=0.0, tangential_noise_std=0.0)
        den = denoise_meshes(scan, radius=None, crease_angle_deg=20.0)
        geoms = {"clean": (spec.refined(args.gt_max_edge), True),
                 "scan, noise-free": (quiet, True), "scan": (scan, True),
                 "scan, denoised": (den, True), "denoised, nominal": (den, False),
                 "denoised, auto-shaded": (auto_shaded(den), True),
                 "scaffold": (prepare_scaffold(scan), True)}
        table[name] = {k: _corr(spec, g, radar, ra_ref, t, args.depth) for k, (g, t) in geoms.items()}
        print(name, {k: round(v, 3) for k, v in table[name].items()}, flush=True)
        _write(table, args.out)
    return 0


def _write(table, out):
    with open(os.path.join(out, "scaffold_ceiling.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", *ROWS])
        for name, r in table.items():
            w.writerow([name, *(f"{r[k]:.4f}" for k in ROWS)])
    lines = ["# RA correlation with the true materials, by geometry (no fit)", "",
             "| scene | " + " | ".join(ROWS) + " |", "|---" * (len(ROWS) + 1) + "|"]
    for name, r in table.items():
        lines.append(f"| {name} | " + " | ".join(f"{r[k]:.3f}" for k in ROWS) + " |")
    vals = np.array([[r[k] for k in ROWS] for r in table.values()])
    lines.append("| **mean** | " + " | ".join(f"**{v:.3f}**" for v in vals.mean(axis=0)) + " |")
    with open(os.path.join(out, "scaffold_ceiling.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
