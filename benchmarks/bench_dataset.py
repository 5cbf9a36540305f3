"""Frames per second of ``sionna-mmir dataset`` with 1 and 2 local workers.

Run from the repository root::

    python benchmarks/bench_dataset.py [benchmarks/dataset_awr1843.json] [--repeat 2]

Rows: ``local`` (one process, Dr.Jit's default thread count), ``ray 1`` and
``ray 2`` (that many Ray tasks at a time, one Dr.Jit thread each).  For Ray,
``ray.init`` is timed apart (``startup``); ``frames/s`` counts the rendering
and writing of all shards, workers' start, imports, scene loads and kernel
compilation included.  Prints a Markdown table.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _one(spec, mode: str, workers: int) -> tuple:
    from sionna_mmir.dataset import run_dataset

    out = tempfile.mkdtemp(prefix="bench_ds_")
    shutil.rmtree(out)
    startup = 0.0
    ray = None
    if mode == "ray":
        import ray

        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        t0 = time.perf_counter()
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False,
                 runtime_env={"env_vars": {"PYTHONPATH": root}})
        startup = time.perf_counter() - t0
    try:
        stats = run_dataset(spec, out, workers=workers, progress=False)
    finally:
        if ray is not None:
            ray.shutdown()
        shutil.rmtree(out, ignore_errors=True)
    return stats["frames"] / stats["seconds"], stats["seconds"], startup


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("spec", nargs="?", default=os.path.join(os.path.dirname(__file__),
                                                           "dataset_awr1843.json"))
    p.add_argument("--repeat", type=int, default=1)
    args = p.parse_args()
    from sionna_mmir.dataset import load_spec

    spec = load_spec(args.spec)
    print(f"{spec.num_frames} frames, {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.2f} at start\n")
    print("| run | workers | frames/s | render s | Ray startup s |")
    print("|---|---|---|---|---|")
    for _ in range(args.repeat):
        for mode, workers in (("local", 1), ("ray", 1), ("ray", 2)):
            fps, seconds, startup = _one(spec, mode, workers)
            print(f"| {mode} | {workers} | {fps:.2f} | {seconds:.1f} | "
                  f"{startup:.1f} |", flush=True)
    print(f"\nload average at end {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
