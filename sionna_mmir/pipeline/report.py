"""The ``loop`` report: ``report.json``, ``report.md``, pictures, model and scene.

``report.json`` keys:

``first``
    metrics of the base model (fitted scene, refined per object and pose in
    the ADC domain), before any diagnosis
``final``
    metrics after every adoption
``scene_mismatch``
    what the scene refit absorbed: per-object gains, radar pose offset and
    every adopted scene-side effect
``adoptions``
    per adopted effect: ``name``, ``side`` (scene / sensor), ``verdict``,
    ``before``, ``after``, ``unexplained`` (the residual's excess over the
    noise floor after it), its parameters, the round's wall ``seconds``
    (``rank``, ``adopt``), ``starts`` (2 where the adoption's first fit was
    undone and a second start kept) and the ranking that chose it (per candidate:
    held-out gain, score, ``energy_change_db``, the held-out residual energy
    change, and ``fit_s``, the seconds of its fold fits)
``unexplained``
    where the final residual exceeds the noise floor (range / beat
    frequency, channels, chirps, samples)
``stop_reason``
    why the diagnosis ended
``vetoed``
    adoptions undone (``round``, ``name``) because their joint refit raised
    the residual energy (``residual_energy_db`` before and after) or came to
    need a higher gain floor than the held-out gain per sample the
    candidate had shown (``gain_floor``: gain, floor; a mover at rest)
``timings``
    seconds per stage

Metrics (:func:`sionna_mmir.residual.scoring.score`): RA correlation, PSNR,
RMSE, ADC log-magnitude MSE, residual energy [dB re. the capture].
"""
from __future__ import annotations

import json
import os

import numpy as np

from ..residual.localise import localise
from ..residual.report import METRICS, write_figures


def _verdict(adoption, side: str) -> str:
    """One line on why the adopted effect won its round: its own held-out
    score (not necessarily the round's highest: a candidate that failed an
    acceptance rule may have scored more) and the best of the other side."""
    ranks = adoption.candidates
    best = next((c for c in ranks if c.name == adoption.name), ranks[0] if ranks else None)
    other = [c for c in ranks if c.name != adoption.name and
             (c.name in _SCENE) != (side == "scene")]
    margin = "" if not other else (f"; best {'sensor' if side == 'scene' else 'scene-side'} "
                                    f"alternative {other[0].name} scored {other[0].score:.1f}")
    gain = adoption.before["residual_energy_db"] - adoption.after["residual_energy_db"]
    return (f"{side} effect adopted: held-out score {best.score:.1f} nats{margin}; residual "
            f"{gain:+.2f} dB lower" if best is not None else f"{side} effect adopted")


#: names of scene-side candidates (stage 0)
_SCENE = {"object_gain", "object_delay", "object_shift", "pose_offset", "object_pattern", "missing_scatterer",
          "moving_scatterer", "multipath_ghost"}


def loop_document(loop) -> dict:
    """The content of ``report.json`` for a finished :class:`~.loop.Loop`."""
    d = loop.run.result()
    model = d.model
    y = model.y * model.scale
    adoptions = []
    for a in d.adoptions:
        side = "scene" if a.name in _SCENE else "sensor"
        adoptions.append({"name": a.name, "side": side, "verdict": _verdict(a, side),
                          "before": a.before, "after": a.after,
                          "unexplained": localise(model.ctx, a.residual_after),
                          "params": a.params, "seconds": a.seconds, "starts": a.starts,
                          "candidates": [c.to_dict() for c in a.candidates]})
    mismatch = {"base_refinement": loop.scene_mismatch or {},
                "final": loop.model.scene_mismatch(),
                "adopted": [a["name"] for a in adoptions if a["side"] == "scene"]}
    return {"capture": str(loop.req.capture), "radar": loop.model.radar.name,
            "scene": loop.req.scene, "objects": list(loop.model.basis.names),
            "info": loop.info, "first": d.first, "final": d.final,
            "scene_mismatch": mismatch, "adoptions": adoptions,
            "sensor_effects": [a["name"] for a in adoptions if a["side"] == "sensor"],
            "unexplained": localise(model.ctx, y - model.mean_adc()),
            "unexplained_domains": d.unexplained,
            "last_candidates": [c.to_dict() for c in d.last_candidates],
            "stop_reason": d.settings.get("stop_reason"), "vetoed": d.settings.get("vetoed", []),
            "settings": d.settings,
            "timings": {k: round(v, 2) for k, v in loop.timings.items()}}


def _row(name, m):
    return f"| {name} | " + " | ".join(f"{m[k]:.4g}" for k in METRICS) + " |"


def _veto_reason(v: dict) -> str:
    """Why an adoption was undone, in words (a ``report.json: vetoed`` entry)."""
    if "gain_floor" in v:
        got, floor = v["gain_floor"]
        return (f"its refit moves as the static scene does and needs {floor:.3f} nats per "
                f"held-out sample; it gained {got:.3f}")
    return (f"its joint refit took the residual from {v['residual_energy_db'][0]:.2f} to "
            f"{v['residual_energy_db'][1]:.2f} dB")


def _calibration_line(cal) -> list:
    """The RA fit target's per-channel calibration, in words (or nothing)."""
    if not cal:
        return []
    what = "phase-calibrated per channel" if cal["applied"] else "the raw capture's map"
    return [f"Range-azimuth fit target: {what} (RA corr with the initial scene "
            f"{cal['ra_corr_raw']:.3f} raw, {cal['ra_corr_calibrated']:.3f} calibrated).", ""]


def loop_markdown(doc: dict) -> str:
    """``report.md``: the error before and after every adoption, and what is left."""
    head = "| model | " + " | ".join(METRICS) + " |\n|---|" + "---|" * len(METRICS)
    L = [f"# sionna-mmir loop: {doc['capture']}", "",
         f"Radar {doc['radar']}; scene: {doc['scene']} ({', '.join(doc['objects'])}).", "",
         *_calibration_line(doc["info"].get("target_calibration")),
         "## Error before and after", "", head, _row("first (scene refined)", doc["first"])]
    L += [_row(f"+ {a['name']} ({a['side']})", a["after"]) for a in doc["adoptions"]]
    L += [f"- vetoed {v['name']} in round {v['round'] + 1}: {_veto_reason(v)}"
          for v in doc["vetoed"]]
    L += ["", f"Stopped: {doc['stop_reason']}.", "",
          f"Sensor effects adopted: {', '.join(doc['sensor_effects']) or 'none'}.", "",
          "## Scene mismatch (absorbed by the scene refit)", "", "```",
          json.dumps(doc["scene_mismatch"], indent=1)[:3000], "```", ""]
    for k, a in enumerate(doc["adoptions"]):
        secs = a.get("seconds") or {}
        L += [f"## Adoption {k + 1}: {a['name']}", "", a["verdict"], ""]
        if secs:
            stages = ", ".join(f"{k[len('adopt_'):].replace('_', ' ')} {v:.1f} s"
                               for k, v in secs.items() if k.startswith("adopt_"))
            L += [f"Round: ranking {secs['rank']:.1f} s, adoption {secs['adopt']:.1f} s"
                  + (f" ({stages})" if stages else "") + ".", ""]
        L += ["| candidate | params | held-out gain | score | held-out residual change [dB] "
              "| fit [s] |", "|---|---|---|---|---|---|"]
        L += [f"| {c['name']} | {c['n_params']} | {c['gain']:.1f} | {c['score']:.1f} | "
              f"{c.get('energy_change_db', 0.0):+.3f} | {c.get('fit_s', 0.0):.1f} |"
              for c in a["candidates"][:8]]
        L += ["", f"![residual](adopt_{k + 1}_{a['name']}.png)", ""]
    u = doc["unexplained"]
    L += ["## Unexplained", "",
          f"Residual {u['excess_db']:+.2f} dB over the fitted noise floor "
          f"({'significant' if u['significant'] else 'at the floor'}).", "",
          "| range [m] | beat [Hz] | excess [dB] |", "|---|---|---|"]
    L += [f"| {b['range_m']:.3f} | {b['beat_hz']:.0f} | {b['excess_db']:.2f} |"
          for b in u["range_bins"]]
    L += ["", "![RA](ra_first_final.png)", "", "![range](range_profile.png)", "",
          "![channels](channels.png)", "", "Seconds per stage: " +
          ", ".join(f"{k} {v}" for k, v in doc["timings"].items()), ""]
    return "\n".join(L)


def write_loop_report(loop, folder: str) -> dict:
    """Write ``report.json``, ``report.md``, pictures, ``model.h5`` (the final
    model's render) and ``scene_mmir.ply`` (the fitted scene) into ``folder``."""
    from ..captures.capture import Capture
    from ..fit.export import save_fitted_ply

    doc = loop_document(loop)
    with open(os.path.join(folder, "report.json"), "w") as f:
        json.dump(doc, f, indent=1, default=float)
    with open(os.path.join(folder, "report.md"), "w") as f:
        f.write(loop_markdown(doc))
    write_figures(loop.run.result(), folder, os.path.basename(str(loop.req.capture)))
    model = loop.model
    Capture(frames=model.render().astype(np.complex64), radar=model.radar,
            source="sionna-mmir loop", metadata={"capture": str(loop.req.capture)}).save(
        os.path.join(folder, "model.h5"), overwrite=True)
    if model.latents is not None:
        save_fitted_ply(model.mmir, model.latents, os.path.join(folder, "scene_mmir.ply"),
                        overwrite=True)
    return doc
