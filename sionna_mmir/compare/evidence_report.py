"""Tables of the evidence experiments (cross-truth, transfer, ablations) from cell results.

Each function takes the result dicts of
:func:`~sionna_mmir.compare.evidence.fit_cell` /
:func:`~sionna_mmir.compare.evidence.transfer_cell` and returns rows or
Markdown lines; every figure is printed beside the truth it is scored
against, so no number can be read without knowing which renderer produced
its reference.
"""
from __future__ import annotations

import csv
import json
import os

import numpy as np

#: what each truth is, in one line (table legends)
TRUTH_LABELS = {
    "mmir": "mmIR facet quadrature (mmIR's own solver: self-referential for mmIR)",
    "sionna": "Sionna RT PathSolver, objects cut into their true material regions, each "
              "with its true surface mean (Sionna's own renderer: self-referential for the "
              "Sionna baseline)",
    "independent": "independent NumPy physical-optics reference (shares no code with either)",
}
#: display names of the models
MODEL_LABELS = {"sionna": "Sionna RT", "table2": "mmIR"}


def model_label(model: str) -> str:
    """Display name of a model key (``"sionna"``, a variant name)."""
    return MODEL_LABELS.get(model, f"mmIR ({model})")


def mean_std(values) -> tuple:
    """``(mean, std, n)`` over the finite entries of ``values``."""
    x = np.asarray([v for v in values if v is not None], dtype=float)
    x = x[np.isfinite(x)]
    if not x.size:
        return float("nan"), float("nan"), 0
    return float(x.mean()), float(x.std()), int(x.size)


def fmt_ms(values, fmt: str = "{:.3f}", sd_fmt: str | None = None) -> str:
    """``"m +/- s"`` of ``values`` (``"n/a"`` when none is finite); ``sd_fmt``
    formats ``s`` (default ``fmt``)."""
    m, s, n = mean_std(values)
    return "n/a" if n == 0 else f"{fmt.format(m)} +/- {(sd_fmt or fmt).format(s)}"


def metric(result: dict, stage: str, key: str = "ra_correlation") -> float:
    """``result[stage][key]`` or NaN."""
    return float((result.get(stage) or {}).get(key, float("nan")))


def grid(results: list, row_key: str, col_key: str) -> dict:
    """``{(row, col): [results]}`` grouping of cell results."""
    out: dict = {}
    for r in results:
        out.setdefault((r[row_key], r[col_key]), []).append(r)
    return out


def summary_lines(results: list, rows: list, cols: list, *, row_key: str, col_key: str,
                  stage: str = "after", key: str = "ra_correlation",
                  row_label=model_label, col_label=str) -> list:
    """Markdown ``rows x cols`` table of ``mean +/- std`` of ``result[stage][key]``.

    Each cell also gives the number of scenes it averages (``n``).
    """
    g = grid(results, row_key, col_key)
    lines = ["| | " + " | ".join(col_label(c) for c in cols) + " |",
             "|---|" + "---|" * len(cols)]
    for r in rows:
        cells = []
        for c in cols:
            vals = [metric(x, stage, key) for x in g.get((r, c), [])]
            n = mean_std(vals)[2]
            cells.append(f"{fmt_ms(vals)} (n={n})" if n else "not run")
        lines.append(f"| {row_label(r)} | " + " | ".join(cells) + " |")
    return lines


def per_scene_lines(results: list, scenes: list, columns: list) -> list:
    """Markdown per-scene table; ``columns`` is ``[(header, fn(results_of_scene) -> str)]``."""
    lines = ["| scene | " + " | ".join(h for h, _ in columns) + " |",
             "|---|" + "---|" * len(columns)]
    for s in scenes:
        sel = [r for r in results if r["scene"] == s]
        lines.append(f"| {s} | " + " | ".join(fn(sel) for _, fn in columns) + " |")
    return lines


def pick(results: list, **where) -> list:
    """Results whose fields equal ``where``."""
    return [r for r in results if all(r.get(k) == v for k, v in where.items())]


def cell_value(results: list, stage: str, key: str = "ra_correlation", fmt="{:.3f}", **where):
    """Formatted ``result[stage][key]`` of the one result matching ``where`` (``-`` if none)."""
    sel = pick(results, **where)
    return fmt.format(metric(sel[0], stage, key)) if sel else "-"


def write_rows(results: list, out_dir: str, stem: str, stages=("before", "after"),
               keys=("ra_correlation", "ra_psnr", "ra_ssim", "ra_rmse")) -> tuple:
    """``<stem>.csv`` (one row per cell) and ``<stem>.json`` (the raw results)."""
    os.makedirs(out_dir, exist_ok=True)
    csv_path = os.path.join(out_dir, stem + ".csv")
    with open(csv_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["truth", "scene", "model"] + [f"{s}_{k}" for s in stages for k in keys]
                   + ["s_per_it", "wall_s"])
        for r in results:
            w.writerow([r["truth"], r["scene"], r["model"]]
                       + [f"{metric(r, s, k):.6g}" for s in stages for k in keys]
                       + [f"{float(r.get('s_per_it', float('nan'))):.4g}",
                          f"{float(r.get('wall_s', float('nan'))):.4g}"])
    json_path = os.path.join(out_dir, stem + ".json")
    with open(json_path, "w") as f:
        json.dump(results, f, indent=1, default=float)
    return csv_path, json_path


def model_truth_columns(truths: list, header: str, cell, models=("table2", "sionna")) -> list:
    """Per-scene table columns, one per (truth, model): ``(title, fn(sel))``.

    ``header`` formats the title from ``label`` and ``truth``; ``cell(sel, truth,
    model)`` formats the cell of the scene's results ``sel``.
    """
    cols = []
    for t in truths:
        for m in models:
            cols.append((header.format(label=model_label(m), truth=t),
                         lambda sel, t=t, m=m: cell(sel, t, m)))
    return cols


def write_markdown(lines: list, out_dir: str, stem: str) -> str:
    """Write ``<stem>.md`` under ``out_dir``, print it, return its path."""
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, stem + ".md")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    return path


def leader_notes(results: list, truths: list, models=("table2", "sionna"),
                 stage: str = "after") -> list:
    """One line per truth: which model leads the mean RA corr, and by how much.

    Means are taken over the scenes every model has a result for (paired), so
    a missing cell cannot tilt the comparison.
    """
    out = []
    for t in truths:
        per_model = {m: {r["scene"]: metric(r, stage) for r in pick(results, truth=t, model=m)}
                     for m in models}
        scenes = sorted(set.intersection(*(set(v) for v in per_model.values())))
        if not scenes:
            out.append(f"- truth `{t}`: no scene with every model run")
            continue
        means = {m: float(np.mean([v[s] for s in scenes])) for m, v in per_model.items()}
        best = max(means, key=means.get)
        gap = means[best] - max(v for m, v in means.items() if m != best)
        wins = {m: sum(per_model[m][s] >= max(per_model[k][s] for k in models) for s in scenes)
                for m in models}
        out.append(f"- truth `{t}` ({len(scenes)} paired scenes): {model_label(best)} leads the "
                   f"mean RA corr by {gap:.3f} ("
                   + ", ".join(f"{model_label(m)} {means[m]:.3f}, best on {wins[m]}"
                               for m in models)
                   + ")")
    return out


def compute_minutes(results: list) -> float:
    """Sum of the cells' wall times [min] (each cell ran in its own interpreter)."""
    return float(sum(float(r.get("wall_s", 0.0)) for r in results)) / 60.0


def table_parser(doc: str, out_dir: str, stem: str, models=("table2", "sionna")):
    """The options every evidence table script shares (an
    :class:`argparse.ArgumentParser`): ``--scenes``, ``--truths``,
    ``--iterations``, ``--models``, ``--cache``, ``--out``, ``--stem``,
    ``--table-only``; a script adds its own."""
    import argparse

    from ..benchmark_scenes import SCENES
    from .evidence import DEFAULT_CACHE
    from .truths import TRUTHS

    p = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--truths", default=",".join(TRUTHS))
    p.add_argument("--iterations", type=int, default=6)
    p.add_argument("--models", default=",".join(models), type=_model_list,
                   help="fitted models: 'sionna' and mmIR variants of "
                        "sionna_mmir.compare.evidence.VARIANTS (default %(default)s)")
    p.add_argument("--cache", default=DEFAULT_CACHE)
    p.add_argument("--out", default=out_dir)
    p.add_argument("--stem", default=stem)
    p.add_argument("--table-only", action="store_true",
                   help="write the table from the cached cells, run nothing")
    return p


def _model_list(text: str) -> str:
    """``--models``: comma-separated ``sionna`` and :data:`~.evidence.VARIANTS`
    names (returned unchanged; an unknown name is a usage error)."""
    import argparse

    from .evidence import VARIANTS

    unknown = [m for m in text.split(",") if m != "sionna" and m not in VARIANTS]
    if unknown or not text:
        raise argparse.ArgumentTypeError(
            f"unknown model {', '.join(unknown) or repr(text)} (choose from sionna, "
            f"{', '.join(VARIANTS)})")
    return text
