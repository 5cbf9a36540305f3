"""Time one radar render of a benchmark scene, for comparing two checkouts.

Renders the hallway of the benchmark catalog (the cascade radar at its pose)
``--calls`` times with the same options and seed and writes the ADC of the
last call (``--out``, ``.npy``) so two checkouts can be checked for equal
output.  It uses only the keyword API that every version of
:class:`~sionna_mmir.paths.RadarPathSolver` accepts, so the same file times
any checkout imported through ``PYTHONPATH``::

    PYTHONPATH=/path/to/checkout python benchmarks/bench_solver_render.py \\
        --sampling random --calls 3 --out /tmp/adc.npy

The process is meant to be timed as a whole (e.g. ``/usr/bin/time -v``), in
pairs against the other checkout, interleaved, on a loaded machine.
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="hallway")
    ap.add_argument("--sampling", default="random", choices=["random", "facets"])
    ap.add_argument("--rays", type=int, default=20_000)
    ap.add_argument("--depth", type=int, default=3)
    ap.add_argument("--calls", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="write the last call's ADC here (.npy)")
    args = ap.parse_args()

    import sionna_mmir
    from sionna_mmir.paths import RadarPathSolver, to_numpy
    from sionna_mmir.radar import RadarConfig
    from sionna_mmir.scene import load_scene
    try:                                   # the catalog's module name differs by version
        from sionna_mmir.benchmark_scenes import build_scene
    except ImportError:
        from sionna_mmir.scenes import build_scene

    spec = build_scene(args.scene)
    radar = RadarConfig.mmwcas(num_chirps=1, position=tuple(spec.radar_position),
                               orientation=tuple(spec.radar_orientation))
    scene = load_scene(spec.objects, materials=dict(spec.materials), radar=radar)
    solver = RadarPathSolver()
    t0 = time.perf_counter()
    for _ in range(args.calls):
        paths = solver(scene, num_rays=args.rays, max_depth=args.depth, seed=args.seed,
                       sampling=args.sampling, min_rel_power=0.0)
        adc = to_numpy(paths.adc(radar))
    dt = time.perf_counter() - t0
    if args.out:
        np.save(args.out, adc)
    print(f"{sionna_mmir.__file__}: {args.calls} x {args.sampling} render "
          f"{dt / args.calls:.3f} s/call, {int(paths.num_paths)} paths")


if __name__ == "__main__":
    main()
