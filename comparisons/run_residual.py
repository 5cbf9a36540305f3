"""Close the loop on the measured captures: residual diagnosis, before / after, evidence.

    .venv/bin/python comparisons/run_residual.py [--base DIR] [--out DIR]

* MMWCAS ``corner_4m7`` / ``corner_6m1``: base model = the mmIR fit of the
  corner scene (``comparisons/residual_base.py`` writes it; run here when
  missing).  Evidence: TI's ``PeakValMat`` / ``RangeMat`` (per-channel peak
  phase, amplitude, position) and ColoRadar's measured ``coupling_calib.txt``.
* AWR1843 moving target (first ``--mover-frames`` of the 1000 chirp sets the
  default ``pairs`` DCA1000 layout reads, 10 ms apart; default 100 = 1 s,
  ``--mover-rounds`` 3):
  base model = the static background (mean over those frames).  Evidence: the model-free per-frame peak track.

Writes ``<out>/<capture>/`` (the ``sionna-mmir residual`` report) and
``<out>/residual_measured.md`` / ``.json`` (tables + evidence).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
CORNERS = ("corner_4m7_slope79.mat", "corner_6m1_slope79.mat")
MOVER = "moving_target_500frames.bin"


def _diagnose(y, base, radar, frame_period=0.0, max_rounds=6):
    from sionna_mmir.effects.library import candidate_effects
    from sionna_mmir.effects import EffectContext, EffectModel
    from sionna_mmir.residual import diagnose

    ctx = EffectContext(radar, num_frames=y.shape[0], frame_period=frame_period)
    return diagnose(EffectModel(ctx, y, base), candidate_effects(None), folds=3,
                    max_rounds=max_rounds,
                    progress=lambda name: print("  scored", name, flush=True))


def _component(d, name):
    for c in d.model.components:
        if c.effect.name == name:
            return c
    return None


def corner(name, measured, base_dir, out):
    from sionna_mmir.captures.capture import Capture
    from sionna_mmir.captures.loader import load_capture
    from sionna_mmir.effects.library.coupling import coupling_profile
    from sionna_mmir.residual.evidence import (coupling_evidence, near_range_evidence,
                                               peak_evidence)
    from sionna_mmir.residual.report import write_report

    cap = load_capture(measured / "mmwcas_corner" / name)
    base_path = os.path.join(base_dir, name.replace(".mat", ".h5"))
    if not os.path.exists(base_path):
        import residual_base

        residual_base.main(["--out", base_dir])
    base = Capture.load(base_path).frames
    d = _diagnose(cap.frames.astype(np.complex128), base, cap.radar)
    write_report(d, os.path.join(out, name.split("_slope")[0]), name,
                 "mmIR fit of the corner scene (comparisons/residual_base.py)", overwrite=True)
    ev = {"peaks_first": peak_evidence(d.first_mean[0].mean(axis=2), cap.extras),
          "peaks_final": peak_evidence(d.model.mean_adc()[0].mean(axis=2), cap.extras)}
    ev["near_range_residual"] = {
        stage: near_range_evidence(res, cap.radar, measured / "coloradar_calib" / "cascade")
        for stage, res in (("first", cap.frames - d.first_mean),
                           ("final", d.model.residual()))}
    comp = _component(d, "coupling")
    if comp is not None:
        prof = coupling_profile(comp.values, d.model.ctx, scale=d.model.scale)
        ev["coupling"] = coupling_evidence(prof, cap.radar, cap.frames[0],
                                           measured / "coloradar_calib" / "cascade")
    return d, ev


def mover(measured, out, frames=100, max_rounds=3):
    from sionna_mmir.captures.loader import load_capture
    from sionna_mmir.residual.evidence import track_evidence
    from sionna_mmir.residual.report import write_report

    cap = load_capture(measured / "awr1843_dca1000" / MOVER)
    y = cap.frames[:frames].astype(np.complex128)          # the first `frames` (1 s at 100)
    base = np.broadcast_to(y.mean(axis=0, keepdims=True), y.shape).copy()
    d = _diagnose(y, base, cap.radar, float(cap.metadata.get("frame_period") or 0.02),
                  max_rounds=max_rounds)
    write_report(d, os.path.join(out, "awr1843_mover"), MOVER,
                 f"static background (mean over the first {len(y)} frames)", overwrite=True)
    ev = {}
    comp = _component(d, "moving_scatterer")
    if comp is not None:
        ev["track"] = track_evidence(comp.values["range"], y, cap.radar)
    return d, ev


def _table(rows):
    keys = ("ra_correlation", "ra_psnr", "ra_rmse", "adc_log_mag_mse", "residual_energy_db")
    L = ["| capture | model | " + " | ".join(keys) + " |", "|---|---|" + "---|" * len(keys)]
    for cap, label, m in rows:
        L.append(f"| {cap} | {label} | " + " | ".join(f"{m[k]:.4g}" for k in keys) + " |")
    return "\n".join(L)


def main(argv=None) -> int:
    from sionna_mmir.captures.measured import find_measured_dir

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--base", default="/tmp/sionna_mmir_residual_base")
    p.add_argument("--out", default=os.path.join(HERE, "residual"))
    p.add_argument("--only", default=None,
                   help="corner_4m7, corner_6m1, mover or evidence (cross-capture checks only)")
    p.add_argument("--mover-frames", type=int, default=100,
                   help="frames of the AWR1843 mover used (10 ms apart; 3 rounds over 100 "
                        "frames take about 8 min on 2 cores; all 1000 would take hours)")
    p.add_argument("--mover-rounds", type=int, default=3, help="adoption rounds on the mover")
    args = p.parse_args(argv)
    measured = find_measured_dir()
    if measured is None:
        print("measured data not found (../shared/data/measured); nothing to do")
        return 1
    sys.path.insert(0, HERE)
    os.makedirs(args.out, exist_ok=True)
    summary_path = os.path.join(args.out, "residual_measured.json")
    summary = json.load(open(summary_path)) if os.path.exists(summary_path) else {}
    jobs = [(n.split("_slope")[0], lambda n=n: corner(n, measured, args.base, args.out))
            for n in CORNERS] + [("mover", lambda: mover(measured, args.out, args.mover_frames,
                                                 args.mover_rounds))]
    for key, job in jobs:
        if args.only and key != args.only:
            continue
        print(key, flush=True)
        d, ev = job()
        summary[key] = {"adopted": d.adopted, "first": d.first, "final": d.final,
                        "steps": [{"effect": a.name, "after": a.after} for a in d.adoptions],
                        "evidence": ev, "unexplained": d.unexplained}
        print(key, "adopted", d.adopted, "RA corr", round(d.first["ra_correlation"], 3), "->",
              round(d.final["ra_correlation"], 3), flush=True)
        with open(summary_path, "w") as f:
            json.dump(summary, f, indent=1, default=float)
    if args.only in (None, "evidence"):
        from sionna_mmir.captures.loader import load_capture
        from sionna_mmir.residual.evidence import near_range_similarity

        caps = [load_capture(measured / "mmwcas_corner" / n) for n in CORNERS]
        summary["cross_capture"] = {"near_range_4m7_vs_6m1": near_range_similarity(
            caps[0].frames, caps[1].frames, caps[0].radar)}
        with open(summary_path, "w") as f:
            json.dump(summary, f, indent=1, default=float)
    rows = []
    for key, s in summary.items():
        if key == "cross_capture":
            continue
        rows.append((key, "first fit", s["first"]))
        rows += [(key, f"+ {st['effect']}", st["after"]) for st in s["steps"]]
    with open(os.path.join(args.out, "residual_measured.md"), "w") as f:
        f.write("# Residual loop on the measured captures\n\n" + _table(rows) + "\n\n"
                "## Independent evidence\n\n```\n"
                + json.dumps({k: (s if k == "cross_capture" else s["evidence"])
                              for k, s in summary.items()}, indent=1)
                + "\n```\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
