"""Reproduce comparisons/<truth>_truth_oracle.{md,json} (one command per truth).

    .venv/bin/python comparisons/run_sionna_truth_oracle.py [--scenes a,b] [--truth sionna|mmir|independent]

How much a truth's materials are worth to each model, on each
sensor, with no fitting: mmIR (the cross-truth table's ``table2`` model,
default beams) and the Sionna RT baseline (30k rays per Tx element) on the
LiDAR-like scaffold, rendered once with the nominal ITU classes (the fits'
start) and once with the truth's own materials (the oracle), scored against
the ``sionna`` truth's cascade and AWR1843 captures (RA correlation, two
evaluation seeds).  The truth holds one material per region (each object
cut at its patches, ``true_region_materials``): mmIR's oracle gives every
scaffold vertex the eps', eps'' and thickness of the region it lies in
(``region_names``; its roughness terms stay nominal, the truth holds none);
Sionna RT, one material per object, gets each object's surface mean
(``sionna_material_values``).  Under the ``mmir`` or ``independent`` truth
(``--truth``), which render the true per-vertex materials, mmIR's oracle is
the full true parameter vector at each scaffold vertex
(``true_vertex_materials``).  The gain of the oracle bounds what a
material fit can carry from one sensor to the other under that truth
(``comparisons/<truth>_truth_oracle.{md,json}``).  One interpreter per
scene; results cached under ``--cache``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
SENSORS = ("cascade", "awr1843")


def _oracle_mmir(spec, meshes, radar, regions):
    """``(model, nominal latents, oracle latents)`` of the table's mmIR model: each
    scaffold vertex gets the truth's eps', eps'' and thickness of its region
    (``sionna``) or the whole true parameter vector at its position (the
    per-vertex truths, ``regions`` None)."""
    import numpy as np

    from sionna_mmir.benchmark_scenes.materials import region_names, true_vertex_materials
    from sionna_mmir.compare.evidence import TABLE2, mmir_model
    from sionna_mmir.fit import reparam

    m = mmir_model(spec, meshes, radar, TABLE2)
    z0 = m.latents()
    z1 = dict(z0)
    for name, mesh in meshes.items():
        phys = np.array(reparam.to_physical(z0[f"{name}.materials"]), dtype=float)
        if regions is None:
            phys = true_vertex_materials(spec, name, mesh.vertices)
        else:
            truth_p = np.stack([regions[r][2] for r in region_names(spec, name, mesh.vertices)])
            phys[:, [0, 1, 5]] = truth_p[:, [0, 1, 5]]
        z1[f"{name}.materials"] = reparam.to_latent(phys)
    return m, z0, z1


def one_scene(scene: str, cache: str, truth: str = "sionna") -> dict:
    """Nominal and oracle RA corr of both models on both sensors of ``scene``."""
    from sionna_mmir.benchmark_scenes import build_scene
    from sionna_mmir.compare.evidence import Budget, scaffold, sionna_model
    from sionna_mmir.compare.harness import evaluate, target_ra
    from sionna_mmir.benchmark_scenes.materials import true_region_materials
    from sionna_mmir.compare.truths import cached_truth, sionna_material_values

    spec = build_scene(scene, seed=0)
    meshes = scaffold(spec)
    values = {k: v for k, v in sionna_material_values(spec).items() if k.split(".")[0] in meshes}
    regions = true_region_materials(spec) if truth == "sionna" else None
    out = {"scene": scene}
    for sensor in SENSORS:
        cap = cached_truth(cache, truth, spec, sensor)
        ra_ref = target_ra(cap.frames, cap.radar)
        m, z0, z1 = _oracle_mmir(spec, meshes, cap.radar, regions)
        for tag, z in (("nominal", z0), ("oracle", z1)):
            metrics = evaluate(m, z, ra_ref, cap.frames[0])[0]
            out[f"table2.{sensor}.{tag}"] = metrics["ra_correlation"]
        del m
        s = sionna_model(spec, meshes, cap.radar, Budget())
        z0 = s.latents()
        s.baseline.set_values(values)
        z1 = s.latents()
        for tag, z in (("nominal", z0), ("oracle", z1)):
            metrics = evaluate(s, z, ra_ref, cap.frames[0])[0]
            out[f"sionna.{sensor}.{tag}"] = metrics["ra_correlation"]
        del s
    return out


def markdown(rows, scenes, truth: str = "sionna") -> list:
    import numpy as np

    from sionna_mmir.compare.evidence_report import TRUTH_LABELS

    if truth == "sionna":
        what = ("the truth's own eps', eps'' and thickness, per region for mmIR (each scaffold "
                "vertex takes its region's), per object (the surface mean) for Sionna RT, which "
                "holds one material per object")
    else:
        what = ("the true per-vertex parameters at each scaffold vertex for mmIR, the true "
                "per-object surface means (eps', eps'', thickness) for Sionna RT, which holds one "
                "material per object")
    lines = [
        f"# What the `{truth}` truth's materials are worth: nominal vs oracle materials, no fit",
        "",
        "Reproduce: `.venv/bin/python comparisons/run_sionna_truth_oracle.py "
        f"--scenes {','.join(scenes)} --truth {truth}`.",
        "",
        f"Truth: `{truth}` ({TRUTH_LABELS[truth]}; the cross-truth table's cascade and AWR1843 "
        "captures). Models on the LiDAR-like scaffold, no fitting: nominal = the ITU classes "
        f"the fits start from; oracle = {what}. mmIR: the cross-truth `table2` model with "
        "default beams; Sionna RT: the baseline at 30k rays per Tx element. RA correlation, "
        "two evaluation seeds.",
        "",
        "| scene | mmIR cascade nominal -> oracle | mmIR AWR1843 nominal -> oracle | "
        "Sionna RT cascade nominal -> oracle | Sionna RT AWR1843 nominal -> oracle |",
        "|---|---|---|---|---|",
    ]
    keys = [f"{m}.{s}" for m in ("table2", "sionna") for s in SENSORS]
    for r in rows:
        lines.append(f"| {r['scene']} | " + " | ".join(
            f"{r[k + '.nominal']:.3f} -> {r[k + '.oracle']:.3f}" for k in keys) + " |")
    if rows:
        lines.append("| mean | " + " | ".join(
            f"{np.mean([r[k + '.nominal'] for r in rows]):.3f} -> "
            f"{np.mean([r[k + '.oracle'] for r in rows]):.3f}" for k in keys) + " |")
    return lines


def main(argv=None) -> int:
    from sionna_mmir.benchmark_scenes import SCENES
    from sionna_mmir.compare.evidence import DEFAULT_CACHE
    from sionna_mmir.compare.truths import cache_label

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--cache", default=DEFAULT_CACHE)
    p.add_argument("--out", default=HERE)
    p.add_argument("--truth", default="sionna", choices=["sionna", "mmir", "independent"])
    p.add_argument("--one", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.one:
        print(json.dumps(one_scene(a.one, a.cache, a.truth)))
        return 0
    scenes, rows = a.scenes.split(","), []
    for scene in scenes:
        path = os.path.join(a.cache, "cells", f"oracle_{cache_label(a.truth)}_{scene}.json")
        if not os.path.exists(path):
            run = subprocess.run([sys.executable, os.path.abspath(__file__), "--one", scene,
                                  "--cache", a.cache, "--truth", a.truth],
                                 capture_output=True, text=True)
            if run.returncode != 0:
                print(f"{scene}: exit {run.returncode}\n{run.stderr[-2000:]}", file=sys.stderr)
                continue
            os.makedirs(os.path.dirname(path), exist_ok=True)
            with open(path, "w") as f:
                f.write(run.stdout.strip().splitlines()[-1])
        with open(path) as f:
            rows.append(json.load(f))
        print(rows[-1], flush=True)
    stem = os.path.join(a.out, f"{a.truth}_truth_oracle")
    with open(stem + ".json", "w") as f:
        json.dump(rows, f, indent=1)
    lines = markdown(rows, scenes, a.truth)
    with open(stem + ".md", "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
