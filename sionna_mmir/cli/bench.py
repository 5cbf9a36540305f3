"""``sionna-mmir bench``: seconds per fit iteration, mmIR vs Sionna RT, same run.

The work is :func:`sionna_mmir.compare.bench.run_bench`.
"""
from __future__ import annotations

import json

from ..paths.options import SolverOptions
from .args import (FORMATTER, add_out, add_scaffold, add_solver, positive, scaffold_options,
                   solver_options)


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help="seconds per fit iteration: mmIR vs Sionna RT, same run",
                       formatter_class=FORMATTER)
    p.add_argument("--scene", default="hallway",
                   help="benchmark scene (sionna_mmir.benchmark_scenes)")
    add_solver(p, SolverOptions.fit(num_rays=10_000), fields=("rays", "depth", "sampling",
                                                              "min_rel_power"))
    p.add_argument("--sionna-depth", type=int, default=3, help="Sionna RT max depth")
    p.add_argument("--sionna-samples", type=int, default=None,
                   help="Sionna samples per source (default: --rays)")
    add_scaffold(p, "none")
    p.add_argument("--learn", default="materials,beam",
                   help="what mmIR learns, comma-separated (the benchmark table's fits learn "
                        "materials and beam patterns)")
    p.add_argument("--repeat", type=int, default=3, help="interleaved timing rounds")
    p.add_argument("--max-triangles", type=int, default=50_000, help="LiDAR mesh budget")
    add_out(p, "write the figures to this JSON file", required=False)
    p.set_defaults(run=run)


def run(args) -> int:
    from ..compare.bench import BenchRequest, bench_table, run_bench

    for flag, value in (("--repeat", args.repeat), ("--sionna-depth", args.sionna_depth),
                        ("--max-triangles", args.max_triangles)):
        positive(value, flag)
    if args.sionna_samples is not None:
        positive(args.sionna_samples, "--sionna-samples")
    req = BenchRequest(scene=args.scene, solver=solver_options(args),
                       scaffold=scaffold_options(args),
                       learn=tuple(x for x in args.learn.split(",") if x),
                       sionna_depth=args.sionna_depth, sionna_samples=args.sionna_samples,
                       repeat=args.repeat, max_triangles=args.max_triangles)
    out = run_bench(req)
    print(bench_table(out))
    if args.out:
        from ..utils.atomic import atomic_path

        with atomic_path(args.out, overwrite=args.overwrite) as tmp:
            with open(tmp, "w") as f:
                json.dump(out, f, indent=1)
    return 0
