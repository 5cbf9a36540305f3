"""Table 2 of the paper (mmIR vs Sionna RT) as Markdown + CSV, and PNG figures."""
from __future__ import annotations

import csv
import os

import numpy as np

METRICS = (("ra_correlation", "RA corr", "{:.3f}"), ("ra_psnr", "PSNR [dB]", "{:.2f}"),
           ("ra_ssim", "SSIM", "{:.3f}"), ("ra_rmse", "RMSE", "{:.4f}"),
           ("adc_log_mag_mse", "ADC log-mag MSE [dB^2]", "{:.2f}"),
           ("adc_minmax_mag_mse", "ADC min-max mag MSE", "{:.4f}"))


def write_table(rows: list[dict], out_dir: str, stem: str = "table2") -> tuple[str, str]:
    """``rows``: dicts with ``scene``, ``model`` and the metric keys (+ ``s_per_it``).

    Writes ``<stem>.md`` (per scene, then mean +/- std per model) and
    ``<stem>.csv``; returns both paths.
    """
    os.makedirs(out_dir, exist_ok=True)
    keys = [m[0] for m in METRICS] + ["s_per_it"]
    csv_path = os.path.join(out_dir, stem + ".csv")
    with open(csv_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", "model"] + keys)
        for r in rows:
            w.writerow([r["scene"], r["model"]] + [f"{r.get(k, float('nan')):.6g}" for k in keys])
    head = "| scene | model | " + " | ".join(m[1] for m in METRICS) + " | s / iter |"
    lines = [head, "|" + "---|" * (len(METRICS) + 3)]
    for r in rows:
        vals = [fmt.format(r.get(k, float("nan"))) for k, _, fmt in METRICS]
        lines.append(f"| {r['scene']} | {r['model']} | " + " | ".join(vals)
                     + f" | {r.get('s_per_it', float('nan')):.2f} |")
    for model in sorted({r["model"] for r in rows}):
        sel = [r for r in rows if r["model"] == model]
        vals = []
        for k, _, fmt in METRICS:
            x = np.array([r.get(k, np.nan) for r in sel], dtype=float)
            x = x[np.isfinite(x)]
            m, sd = (x.mean(), x.std()) if x.size else (float("nan"), float("nan"))
            vals.append(f"{fmt.format(m)} +/- {fmt.format(sd)}")
        sps = np.array([r.get("s_per_it", np.nan) for r in sel], dtype=float)
        sp = float(np.nanmean(sps)) if np.isfinite(sps).any() else float("nan")
        lines.append(f"| **mean** | {model} | " + " | ".join(vals) + f" | {sp:.2f} |")
    md_path = os.path.join(out_dir, stem + ".md")
    with open(md_path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return md_path, csv_path


def save_panels(path: str, maps: dict, ranges, az, title: str = "") -> None:
    """Side-by-side min-max RA maps (e.g. measured / mmIR / Sionna)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(maps), figsize=(4.2 * len(maps), 3.6), squeeze=False)
    ext = [np.degrees(az[0]), np.degrees(az[-1]), ranges[0], ranges[-1]]
    for axh, (name, m) in zip(axes[0], maps.items()):
        m = np.asarray(m, dtype=float)
        mn = (m - m.min()) / max(m.max() - m.min(), 1e-30)
        axh.imshow(mn, origin="lower", aspect="auto", extent=ext, cmap="viridis")
        axh.set_title(name)
        axh.set_xlabel("azimuth [deg]")
        axh.set_ylabel("range [m]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def save_loss_curves(path: str, curves: dict, title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.4))
    for name, h in curves.items():
        ax.plot(np.arange(1, len(h) + 1), h, label=name)
    ax.set_xlabel("iteration")
    ax.set_ylabel("min-max RA loss")
    ax.set_yscale("log")
    ax.legend()
    if title:
        ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table_rows(scene: str, sides: dict) -> list[dict]:
    """Rows for :func:`write_table` from ``{label: SideResult}``."""
    return [{"scene": scene, "model": k, **v.metrics_after, "s_per_it": v.seconds_per_it}
            for k, v in sides.items()]


def save_side_figures(ra_path: str, loss_path: str, reference: tuple, sides: dict, ranges, az,
                      title: str = "") -> None:
    """RA panels (``reference = (label, map)`` then each side) and the loss curves."""
    save_panels(ra_path, {reference[0]: reference[1], **{k: v.ra_after for k, v in sides.items()}},
                ranges, az, title=title)
    save_loss_curves(loss_path, {k: v.history for k, v in sides.items()}, title=title)
