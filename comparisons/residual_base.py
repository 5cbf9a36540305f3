"""First fit of the measured corner captures: the base model of the residual loop.

    .venv/bin/python comparisons/residual_base.py [--iterations N] [--out DIR]

For each MMWCAS corner capture: detect the corner, build the corner-reflector
scene (trihedral + an assumed floor, ``sionna_mmir/cli/demo_fit.py``), fit it
with mmIR (materials, normals, beam patterns; the paper's RA loss), and write
the fitted model's render as ``<out>/<capture>.h5`` (a project HDF5 capture),
the input of ``sionna-mmir residual --model``.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

CAPTURES = ("corner_4m7_slope79.mat", "corner_6m1_slope79.mat")


def fit_corner(cap, iterations: int, rays: int = 6000):
    """mmIR fit of the corner scene to ``cap``; returns (render ADC [T,R,C,N], SideResult)."""
    from sionna_mmir.compare.corner_scene import corner_scene_meshes
    from sionna_mmir.compare.harness import run_side
    from sionna_mmir.fmcw.targets import refine_point_target
    from sionna_mmir.paths.options import SolverOptions
    from sionna_mmir.processing.detection import strongest_return
    from sionna_mmir.fit import MMIRModel
    from sionna_mmir.paths.render import to_numpy
    from sionna_mmir.processing.imaging import range_azimuth
    from sionna_mmir.processing.virtual_array import VirtualArray
    from sionna_mmir.scene import load_scene

    radar = cap.radar
    ra, ranges, az = range_azimuth(cap.adc, radar)
    r, a, _ = strongest_return(ra, ranges, az, 1.0, radar.max_range * 0.9)
    centre = VirtualArray(radar).phase_centre()
    r, a_deg = refine_point_target(cap.adc, radar, r, np.degrees(a), centre)
    meshes = corner_scene_meshes(r, np.radians(a_deg), centre)
    cone = min(abs(a_deg) + 6.0, 90.0)
    mm = MMIRModel(load_scene(meshes, materials={"corner": "metal", "floor": "concrete"},
                              radar=radar),
                   solver_options=SolverOptions.fit(num_rays=rays, max_depth=3,
                                                    cone_angle_deg=cone))
    side = run_side("mmIR", mm, ra, cap.adc, iterations=iterations, lr=0.05, progress=False)
    renders = [to_numpy(mm.render(side.extra["latents"], seed=s)[0]) for s in (9001, 9002)]
    return np.mean(renders, axis=0), side


def main(argv=None) -> int:
    from sionna_mmir.captures.capture import Capture
    from sionna_mmir.captures.loader import load_capture
    from sionna_mmir.captures.measured import find_measured_dir

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--iterations", type=int, default=10)
    p.add_argument("--out", default="/tmp/sionna_mmir_residual_base")
    args = p.parse_args(argv)
    measured = find_measured_dir()
    if measured is None:
        print("measured data not found (../shared/data/measured); nothing to do")
        return 1
    os.makedirs(args.out, exist_ok=True)
    for name in CAPTURES:
        cap = load_capture(measured / "mmwcas_corner" / name)
        adc, side = fit_corner(cap, args.iterations)
        path = os.path.join(args.out, name.replace(".mat", ".h5"))
        Capture(frames=adc, radar=cap.radar, source="comparisons/residual_base.py",
                metadata={"model": "mmIR", "capture": name,
                          "ra_correlation": side.metrics_after["ra_correlation"]}).save(
            path, overwrite=True)
        print(f"{name}: mmIR RA corr {side.metrics_before['ra_correlation']:.3f} -> "
              f"{side.metrics_after['ra_correlation']:.3f}; wrote {path}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
