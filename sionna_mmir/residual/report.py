"""``residual`` report: JSON, Markdown and PNGs of a :class:`~sionna_mmir.residual.diagnosis.Diagnosis`.

Folder layout (written to ``<out>.partial`` and renamed, so a failed run
leaves nothing; an existing report is never replaced without ``overwrite``):

=========================  ====================================================
``residual.json``          settings, first / final metrics, every adoption
                           (before / after, parameters, ranked candidates),
                           the last ranking, the unexplained residual
``residual.md``            the same as tables
``ra_first_final.png``     measured / first model / final model / residuals (dB)
``range_profile.png``      residual energy per range bin, first vs final,
                           negative-frequency (image) half included
``channels.png``           residual energy per virtual channel, first vs final
``adopt_<k>_<name>.png``   residual RA map before / after each adoption
=========================  ====================================================
"""
from __future__ import annotations

import json
import os
import shutil

import numpy as np

from .analysis import residual_domains
from .scoring import model_ra, ra_power

METRICS = ("ra_correlation", "ra_psnr", "ra_ssim", "ra_rmse", "adc_log_mag_mse",
           "residual_energy_db")


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _db_map(m, ref=None, span=40.0):
    m = np.asarray(m, np.float64)
    ref = float(m.max()) if ref is None else float(ref)
    return np.clip(20 * np.log10(np.maximum(m, 1e-30) / max(ref, 1e-30)), -span, 0)


def _panels(path, maps: dict, ranges, az, title, shared_ref=True):
    plt = _plt()
    fig, axes = plt.subplots(1, len(maps), figsize=(3.6 * len(maps), 3.4), squeeze=False)
    ext = [np.degrees(az[0]), np.degrees(az[-1]), ranges[0], ranges[-1]]
    ref = max(float(np.max(m)) for m in maps.values()) if shared_ref else None
    for ax, (name, m) in zip(axes[0], maps.items()):
        im = ax.imshow(_db_map(m, ref), origin="lower", aspect="auto", extent=ext,
                       cmap="viridis", vmin=-40, vmax=0)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("azimuth [deg]")
        ax.set_ylabel("range [m]")
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.8, label="dB re. strongest")
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _ra(ctx, adc):
    p, rng, az = ra_power(ctx, adc)
    return np.sqrt(p), rng, az


def _range_profile(path, ctx, measured, first_res, final_res):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.4))
    order = np.argsort(ctx.band_frequencies())
    r = ctx.band_ranges[order]
    e = float(np.sum(np.abs(measured) ** 2))
    for name, x in (("measured", measured), ("residual, first fit", first_res),
                    ("residual, final", final_res)):
        p = np.sum(np.abs(np.fft.fft(x, axis=-1, norm="ortho")) ** 2, axis=(0, 1, 2, 3)) / e
        ax.plot(r, 10 * np.log10(np.maximum(p[order], 1e-30)), label=name, lw=1)
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("range of the beat frequency [m] (IF band -0.1 .. 0.9 f_s; negative: "
                  "below DC)")
    ax.set_ylabel("energy per bin [dB re. capture]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _channels(path, first_res, final_res):
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.2))
    a = np.sum(np.abs(first_res) ** 2, axis=(0, 3, 4))
    b = np.sum(np.abs(final_res) ** 2, axis=(0, 3, 4))
    ref = max(a.max(), 1e-30)
    for ax, (name, m) in zip(axes, (("first fit", a), ("final", b))):
        im = ax.imshow(10 * np.log10(np.maximum(m / ref, 1e-6)), aspect="auto", cmap="magma",
                       vmin=-40, vmax=0)
        ax.set_title(f"residual energy per channel, {name}", fontsize=9)
        ax.set_xlabel("Rx")
        ax.set_ylabel("Tx")
    fig.colorbar(im, ax=list(axes), shrink=0.8, label="dB")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _row(name, m):
    return f"| {name} | " + " | ".join(f"{m[k]:.4g}" for k in METRICS) + " |"


def _header():
    return ("| model | " + " | ".join(METRICS) + " |\n|---|" + "---|" * len(METRICS))


def _markdown(d, doc: dict) -> str:
    L = [f"# sionna-mmir residual: {doc['capture']}", "",
         f"Base model: {doc['model_source']}. Candidates: {', '.join(d.settings['candidates'])}. "
         f"{d.settings['folds']}-fold cross-validation holding out "
         + ("whole virtual channels (Tx-Rx pairs, all frames and chirps)"
            if d.settings.get("fold_groups") == "channel" else "(frame, Tx, Rx, chirp) cells")
         + f", held-out white floor profiled, mean effects ranked before variance effects, "
         f"penalty {d.settings['penalty_nats_per_param']} nats per parameter "
         "(n: held-out samples).", "",
         "## Error before and after", "", _header(), _row("first fit", d.first)]
    for a in d.adoptions:
        L.append(_row(f"+ {a.name}", a.after))
    L += ["", f"Adopted: {', '.join(d.adopted) or 'nothing'}.", ""]
    for k, a in enumerate(d.adoptions):
        L += [f"## Adoption {k + 1}: {a.name}", "", _header(), _row("before", a.before),
              _row("after", a.after), "", "Ranked candidates (held-out gain, nats):", "",
              "| effect | params | held-out gain | per sample | score |", "|---|---|---|---|---|"]
        L += [f"| {c.name} | {c.n_params} | {c.gain:.1f} | {c.gain_per_sample:.4f} | {c.score:.1f} |"
              for c in a.candidates]
        L += ["", "Fitted parameters:", "", "```", json.dumps(a.params, indent=1)[:4000], "```",
              "", f"![residual before/after](adopt_{k + 1}_{a.name}.png)", ""]
    if d.last_candidates:
        L += ["## Nothing else helps", "", "| effect | params | held-out gain | score |",
              "|---|---|---|---|"]
        L += [f"| {c.name} | {c.n_params} | {c.gain:.1f} | {c.score:.1f} |"
              for c in d.last_candidates]
    u = d.unexplained
    L += ["", "## Unexplained", "",
          f"Residual energy {u['residual_energy_db']:.2f} dB re. the capture.", "",
          "| where | share of the residual |", "|---|---|"]
    L += [f"| {k} | {v:.3f} |" for k, v in u["shares"].items()]
    L += ["", "Strongest residual range bins:", "", "| range [m] | share |", "|---|---|"]
    L += [f"| {p['range_m']:.3f} | {p['share']:.3f} |" for p in u["peaks"]]
    L += ["", "![RA](ra_first_final.png)", "", "![range](range_profile.png)", "",
          "![channels](channels.png)", ""]
    return "\n".join(L)


def write_report(d, out: str, capture: str, model_source: str, overwrite: bool = False) -> str:
    """Write the report folder ``out`` (see module docstring); returns its path."""
    if os.path.exists(out) and not overwrite:
        raise FileExistsError(f"{out}: a report is already there (use --overwrite to replace it)")
    tmp = out.rstrip("/") + ".partial"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    try:
        _write(d, tmp, capture, model_source)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if os.path.exists(out):
        shutil.rmtree(out)
    os.replace(tmp, out)
    return out


def _write(d, tmp, capture, model_source):
    m = d.model
    ctx = m.ctx
    y = m.y * m.scale
    doc = {"capture": capture, "model_source": model_source, "settings": d.settings,
           "first": d.first, "final": d.final,
           "adoptions": [{"name": a.name, "round": a.round, "before": a.before, "after": a.after,
                          "params": a.params, "candidates": [c.to_dict() for c in a.candidates]}
                         for a in d.adoptions],
           "last_candidates": [c.to_dict() for c in d.last_candidates],
           "first_residual": {k: v for k, v in residual_domains(ctx, y, d.first_mean).items()
                              if k != "arrays"},
           "unexplained": d.unexplained}
    with open(os.path.join(tmp, "residual.json"), "w") as f:
        json.dump(doc, f, indent=1, default=float)
    with open(os.path.join(tmp, "residual.md"), "w") as f:
        f.write(_markdown(d, doc))
    write_figures(d, tmp, capture)


def write_figures(d, tmp, capture) -> None:
    """RA panels (measured, first / final model and residual), the residual's
    range profile and channel map, and one before / after panel per adoption."""
    m = d.model
    ctx = m.ctx
    y = m.y * m.scale
    final_mean, final_var = m.mean_variance_numpy()
    final_mean, final_var = final_mean * m.scale, final_var * m.scale ** 2
    first_res = y - d.first_mean
    final_res = y - final_mean
    ra_y, rng, az = _ra(ctx, y)
    maps = {"measured": ra_y,
            "first model": model_ra(ctx, d.first_mean, d.first_variance)[0],
            "final model": model_ra(ctx, final_mean, final_var)[0],
            "residual, first": _ra(ctx, first_res)[0],
            "residual, final": _ra(ctx, final_res)[0]}
    _panels(os.path.join(tmp, "ra_first_final.png"), maps, rng, az, capture)
    _range_profile(os.path.join(tmp, "range_profile.png"), ctx, y, first_res, final_res)
    _channels(os.path.join(tmp, "channels.png"), first_res, final_res)
    for k, a in enumerate(d.adoptions):
        _panels(os.path.join(tmp, f"adopt_{k + 1}_{a.name}.png"),
                {"measured": ra_y, "residual before": _ra(ctx, a.residual_before)[0],
                 "residual after": _ra(ctx, a.residual_after)[0]}, rng, az,
                f"{a.name}: residual before / after")
