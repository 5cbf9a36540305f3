"""Table 2 on the measured MMWCAS corner captures: mmIR vs Sionna RT (one command).

    .venv/bin/python comparisons/run_measured.py [--iterations N]

For ``corner_4m7_slope79.mat`` and ``corner_6m1_slope79.mat`` (from
``../shared/data/measured/mmwcas_corner/`` or ``$SIONNA_MMIR_MEASURED``): the
corner is detected in the measured RA map, a corner-reflector scene is built
there (``sionna_mmir/cli/demo_fit.py``: trihedral + an assumed floor), and
both models are fitted with the same loss, Adam and iteration budget.
Writes ``table2_measured.{md,csv}`` and ``figures/measured_*.png``.

``--calibration self`` first applies TI's phase / frequency calibration
measured on the capture's own corner (``estimate_phase_frequency_calibration``
+ ``phase_frequency_correct``, the procedure behind the file's ``PeakValMat``
/ ``RangeMat``) and writes ``table2_measured_selfcal.*``: both models then
see the calibrated capture (the residual loop shows per-channel delays and
phases are what the uncalibrated fits lack).
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
CAPTURES = ("corner_4m7_slope79.mat", "corner_6m1_slope79.mat")


def _self_calibrated(cap, corner_range):
    """``cap`` with TI's phase / frequency calibration from its own corner applied
    (peak search gated to +/- 0.3 m about ``corner_range``: the corner, not a wall)."""
    from sionna_mmir.captures.capture import Capture
    from sionna_mmir.processing.calibration import (estimate_phase_frequency_calibration,
                                                    phase_frequency_correct)

    r = cap.radar
    bins, peaks = estimate_phase_frequency_calibration(cap.adc, r, min_range=corner_range - 0.3,
                                                       max_range=corner_range + 0.3)
    frames = phase_frequency_correct(cap.frames, r, bins, peaks, r.slope, r.sample_rate,
                                     r.num_samples)
    meta = dict(cap.metadata, calibration="self (own corner, TI procedure)")
    return Capture(np.asarray(frames, dtype=np.complex64), r, meta, cap.source)


def main(argv=None) -> int:
    from sionna_mmir.captures.loader import load_capture
    from sionna_mmir.captures.measured import find_measured_dir
    from sionna_mmir.compare.corner_scene import fit_corner_scene
    from sionna_mmir.fmcw.targets import refine_point_target
    from sionna_mmir.processing.detection import strongest_return
    from sionna_mmir.compare.report import save_side_figures, table_rows, write_table
    from sionna_mmir.processing.imaging import range_azimuth
    from sionna_mmir.processing.virtual_array import VirtualArray

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--iterations", type=int, default=10)
    p.add_argument("--out", default=HERE)
    p.add_argument("--calibration", choices=("none", "self"), default="none")
    args = p.parse_args(argv)
    measured = find_measured_dir()
    if measured is None:
        print("measured data not found (../shared/data/measured); nothing to do")
        return 1
    rows = []
    os.makedirs(os.path.join(args.out, "figures"), exist_ok=True)
    for name in CAPTURES:
        cap = load_capture(measured / "mmwcas_corner" / name)
        radar = cap.radar
        centre = VirtualArray(radar).phase_centre()

        def detect(c):
            ra, ranges, az = range_azimuth(c.adc, radar)
            r, a, _ = strongest_return(ra, ranges, az, 1.0, radar.max_range * 0.9)
            return (ra, ranges, az) + refine_point_target(c.adc, radar, r, np.degrees(a), centre)

        ra, ranges, az, r, a_deg = detect(cap)
        if args.calibration == "self":
            cap = _self_calibrated(cap, r)          # gated at the detected corner
            ra, ranges, az, r, a_deg = detect(cap)
        sides = fit_corner_scene(cap, ra, r, np.radians(a_deg), centre, iterations=args.iterations,
                          progress=False)
        rows += table_rows(name, sides)
        for k, v in sides.items():
            print(f"{name} {k}: RA corr {v.metrics_before['ra_correlation']:.3f} -> "
                  f"{v.metrics_after['ra_correlation']:.3f}", flush=True)
        stem = os.path.join(args.out, "figures", "measured_" + name.split("_slope")[0]
                            + ("_selfcal" if args.calibration == "self" else ""))
        save_side_figures(stem + "_ra.png", stem + "_loss.png", ("measured", ra), sides,
                          ranges, az, title=name)
        write_table(rows, args.out, "table2_measured"
                    + ("_selfcal" if args.calibration == "self" else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
