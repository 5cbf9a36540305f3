"""Cost of specular manifold sampling and coherent FSD beside Sionna RT.

The scene of :mod:`bench_boundary` (the pose-fit scene: spheres, a wall and
a plate partly hiding it, so both curved triangles and occluded chains
occur), the AWR1843, depth 2, ``bench_boundary.RAYS`` random rays. Each row is
forward + backward to the radar pose (mmIR) or to the materials (Sionna RT,
which has no pose gradient), best of ``bench_boundary.REPEATS`` interleaved
rounds after a warm-up.

Run ``python benchmarks/bench_sms_fsd.py`` (prints a Markdown table) or
through pytest with ``-m benchmark``.
"""
from __future__ import annotations

import bench_boundary as bb

DEPTH = 2
ROWS = (("mmIR, image method", {}), ("mmIR, SMS on", {"sms": True}),
        ("mmIR, coherent FSD on", {"fsd_coherent": True}),
        ("mmIR, SMS and coherent FSD on", {"sms": True, "fsd_coherent": True}))


def measure() -> dict:
    """Timings [s] per row and ratios, with a Markdown table under ``"markdown"``."""
    scene, pose_fit = bb._scene()
    fns = [bb._mmir(scene, False, DEPTH, **extra) for _, extra in ROWS]
    fns.append(bb._sionna(pose_fit.meshes(), scene.radar, DEPTH))
    times = bb._best(fns)
    base, ref = times[0], times[-1]
    lines = [f"Speed, forward + backward, depth {DEPTH}, {bb.RAYS} rays, best of {bb.REPEATS} "
             "interleaved rounds (`python benchmarks/bench_sms_fsd.py`):", "",
             "| | seconds | vs image method | vs Sionna RT |", "|---|---|---|---|"]
    for (name, _), t in zip(ROWS + (("Sionna RT PathSolver", None),), times):
        lines.append(f"| {name} | {t:.3f} | {t / base:.2f} | {t / ref:.2f} |")
    return {"seconds": dict(zip([n for n, _ in ROWS] + ["sionna"], times)),
            "markdown": "\n".join(lines)}


if __name__ == "__main__":
    print(measure()["markdown"])
