"""Reproduce comparisons/transfer.{md,csv,json} (one command).

    .venv/bin/python comparisons/run_transfer.py [--iterations N] [--scenes a,b] [--truths t1,t2]

Cross-sensor transfer (the paper's Table 3) on the six benchmark scenes
under each truth: the scene is fitted on the MMWCAS cascade (the cells of
``run_cross_truth.py``, same budget, reused from the cache), frozen, and
rendered for a co-located TI AWR1843 (3 Tx x 4 Rx) placed at the cascade's
pose composed with the single-chip mounting relative to the cascade on the
ColoRadar rig (``coloradar_calib/transforms/base_to_*.txt``).  Scored
against the same truth's AWR1843 capture, before fitting (nominal materials,
default beam shape) and after (the cascade fit's per-vertex materials and
its learned beam *shape*; the per-element gain residuals belong to the
cascade's elements and are dropped).  Sionna RT: its fitted per-object
materials, isotropic elements.
"""
from __future__ import annotations

import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
MODELS = ("table2", "sionna")


def _args(argv):
    from sionna_mmir.compare.evidence_report import table_parser

    p = table_parser(__doc__, HERE, "transfer", MODELS)
    p.add_argument("--only-ready", action="store_true",
                   help="skip cells whose cascade fit or AWR1843 truth is not cached yet "
                        "(for running beside run_cross_truth.py)")
    return p.parse_args(argv)


def _ready(truth, scene, model, budget, cache) -> bool:
    from sionna_mmir.compare.evidence import cell_stem
    from sionna_mmir.compare.truths import truth_path

    return (os.path.exists(cell_stem(cache, "fit", truth, scene, model, budget) + ".json")
            and os.path.exists(truth_path(cache, truth, scene, "awr1843")))


def run(truths, scenes, budget, cache, table_only=False, only_ready=False,
        models=MODELS) -> list:
    """All transfer cells (each needs its cascade fit and the AWR1843 truth)."""
    from sionna_mmir.compare.evidence import cell_stem, load_cell, run_cell

    results = []
    for truth in truths:
        for scene in scenes:
            for model in models:
                res, _ = load_cell(cell_stem(cache, "transfer", truth, scene, model, budget))
                if only_ready and res is None and not _ready(truth, scene, model, budget, cache):
                    continue
                if res is None and not table_only:
                    t0 = time.perf_counter()
                    try:
                        run_cell("truth", truth, scene, "cascade", budget, cache)
                        run_cell("truth", truth, scene, "awr1843", budget, cache)
                        run_cell("fit", truth, scene, model, budget, cache)
                        res = run_cell("transfer", truth, scene, model, budget, cache)
                    except RuntimeError as exc:
                        print(exc, file=sys.stderr, flush=True)
                    print(f"{truth} {scene} {model}: {time.perf_counter() - t0:.0f} s",
                          flush=True)
                if res is not None:
                    results.append(res)
    return results


def _verdict(results, truths, models=MODELS) -> list:
    from sionna_mmir.compare.evidence_report import mean_std, metric, model_label, pick

    out = []
    for t in truths:
        for m in models:
            sel = pick(results, truth=t, model=m)
            if not sel:
                continue
            b = mean_std([metric(r, "before") for r in sel])[0]
            a = mean_std([metric(r, "after") for r in sel])[0]
            gains = sum(metric(r, "after") > metric(r, "before") for r in sel)
            out.append(f"- truth `{t}`, {model_label(m)}: mean RA corr {b:.3f} before -> "
                       f"{a:.3f} after ({'gain' if a > b else 'NO GAIN'} {a - b:+.3f}; "
                       f"after > before on {gains}/{len(sel)} scenes)")
    return out


def markdown(results, truths, scenes, budget, wall_s, models=MODELS) -> list:
    from sionna_mmir.compare.evidence_report import (TRUTH_LABELS, cell_value, compute_minutes,
                                                     model_truth_columns, per_scene_lines,
                                                     summary_lines)

    lines = [
        "# Cross-sensor transfer (Table 3): fit on the MMWCAS cascade, render the AWR1843",
        "",
        "Reproduce: `.venv/bin/python comparisons/run_transfer.py "
        f"--iterations {budget.iterations} --scenes {','.join(scenes)} "
        f"--truths {','.join(truths)}"
        + ("" if tuple(models) == MODELS else f" --models {','.join(models)}") + "` "
        "(reuses the cascade fits of `run_cross_truth.py`; the transfer cells took "
        f"{compute_minutes(results):.0f} min of wall time in all, on 2 CPU cores shared with "
        "other jobs).",
        "",
        f"Budget: the cross-truth fits ({budget.iterations} Adam iterations, lr {budget.lr}, "
        "min-max RA loss) on the cascade; nothing is fitted on the AWR1843. AWR1843 pose: the "
        "cascade's pose composed with the ColoRadar single-chip mounting relative to the "
        "cascade. Transferred for mmIR: per-vertex materials and the learned beam shape "
        "(one cos^q per array side); not transferred: the per-element gain residuals (they "
        "describe the cascade's elements). Sionna RT: fitted per-object materials.",
        "",
        "Truths (the AWR1843 reference each figure is scored against; the cascade fit used "
        "the same truth's cascade capture):",
        "",
    ]
    lines += [f"- `{t}`: {TRUTH_LABELS[t]}" for t in truths]
    for stage in ("before", "after"):
        lines += ["", f"## AWR1843 RA correlation {stage} fitting, mean +/- std over scenes", ""]
        lines += summary_lines(results, list(models), truths, row_key="model", col_key="truth",
                               stage=stage, col_label=lambda t: f"truth: {t}")
    lines += ["", "Acceptance (mean after > mean before, per truth):", ""]
    lines += _verdict(results, truths, models)
    cols = model_truth_columns(truths, "{label} [truth: {truth}] before -> after",
                               lambda sel, t, m: (
                                   f"{cell_value(sel, 'before', truth=t, model=m)} "
                                   f"-> {cell_value(sel, 'after', truth=t, model=m)}"),
                               models=models)
    lines += ["", "## Per scene: AWR1843 RA corr before -> after", ""]
    lines += per_scene_lines(results, scenes, cols)
    return lines


def main(argv=None) -> int:
    from sionna_mmir.compare.evidence import Budget
    from sionna_mmir.compare.evidence_report import write_markdown, write_rows

    a = _args(argv)
    truths, scenes = a.truths.split(","), a.scenes.split(",")
    budget = Budget(iterations=a.iterations)
    t0 = time.perf_counter()
    models = tuple(a.models.split(","))
    results = run(truths, scenes, budget, a.cache, a.table_only, a.only_ready, models)
    wall = time.perf_counter() - t0
    write_rows(results, a.out, a.stem)
    lines = markdown(results, truths, scenes, budget, wall, models)
    write_markdown(lines, a.out, a.stem)
    return 0


if __name__ == "__main__":
    sys.exit(main())
