"""``sionna-mmir residual``: find what a fitted model still gets wrong, and fix it.

Reads a capture (any format ``load_capture`` reads) and a *base model* ADC:

* an HDF5 capture of the fitted model's render (``model_mmir.h5`` that
  ``sionna-mmir fit`` / ``compare`` write; its radar must match the capture's);
* ``static``: the capture's own mean over frames (everything that does not
  move), for multi-frame captures of moving targets;
* ``none``: no base model (effects explain everything).

Then diagnoses the residual with the effects library (cross-validated ranking,
adoption until nothing helps) and writes the report folder (JSON, Markdown,
PNGs; see :mod:`sionna_mmir.residual.report`).
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError, InputValueError


def add_parser(sub) -> None:
    p = sub.add_parser("residual", help="diagnose a fit's residual with the effects library "
                                        "and report the error before and after")
    p.add_argument("capture", help="measured capture (TI .mat, DCA1000 .bin, ColoRadar run, HDF5)")
    p.add_argument("--model", required=True,
                   help="base model: HDF5 capture of the fitted render, 'static' (mean over "
                        "frames) or 'none'")
    p.add_argument("--out", required=True, help="report folder (must not exist unless --overwrite)")
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="frame range of multi-frame captures (default: all)")
    p.add_argument("--calib-dir", default=None, help="ColoRadar calib folder")
    p.add_argument("--effects", default=None,
                   help="comma-separated candidate effects (default: the whole library)")
    p.add_argument("--folds", type=int, default=3)
    p.add_argument("--fold-groups", choices=("auto", "channel", "cell"), default="auto",
                   help="cross-validation hold-out unit: whole virtual channels (auto: when "
                        "the array allows) or single (frame, Tx, Rx, chirp) cells")
    p.add_argument("--max-rounds", type=int, default=6)
    p.add_argument("--penalty", type=float, default=1.0, help="nats per parameter")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--overwrite", action="store_true", help="replace an existing report")


def _frames(text, n):
    if text is None:
        return slice(0, n)
    try:
        a, b = (int(v) if v else None for v in text.split(":"))
    except ValueError:
        raise ConfigError(f"--frames: expected A:B, got {text!r}") from None
    s = slice(a or 0, n if b is None else b)
    if not 0 <= s.start < s.stop <= n:
        raise ConfigError(f"--frames {text}: outside the capture's 0:{n} frames")
    return s


def candidate_effects(names):
    """Library instances for a comma-separated list (None: all)."""
    from ..effects.library import LIBRARY

    if names is None:
        return [cls() for cls in LIBRARY.values()]
    out = []
    for n in (x.strip() for x in names.split(",") if x.strip()):
        if n not in LIBRARY:
            raise ConfigError(f"--effects: unknown effect {n!r}; the library has "
                              f"{sorted(LIBRARY)}")
        out.append(LIBRARY[n]())
    if not out:
        raise ConfigError("--effects: empty list")
    return out


def base_model(spec, cap, frames):
    """The base model ADC ``[F, T, R, C, N]`` for ``--model``."""
    from ..captures.capture import Capture

    y = cap.frames[frames]
    if spec == "none":
        return np.zeros_like(y), "none (effects only)"
    if spec == "static":
        if y.shape[0] < 2:
            raise InputValueError("--model static needs a multi-frame capture (mean over frames)")
        return np.broadcast_to(y.mean(axis=0, keepdims=True), y.shape).copy(), \
            "static background (mean over frames)"
    model = Capture.load(spec)
    if model.radar.adc_shape != cap.radar.adc_shape or not np.allclose(
            [model.radar.start_frequency, model.radar.slope, model.radar.sample_rate],
            [cap.radar.start_frequency, cap.radar.slope, cap.radar.sample_rate], rtol=1e-6):
        raise InputValueError(
            f"{spec}: the model was rendered for a different radar than the capture's "
            f"(shape {model.radar.adc_shape} vs {cap.radar.adc_shape}, slope "
            f"{model.radar.slope:.6g} vs {cap.radar.slope:.6g} Hz/s); render the fit with "
            "the capture's radar")
    m = model.frames
    if m.shape[0] == 1 and y.shape[0] > 1:
        m = np.broadcast_to(m, y.shape)
    elif m.shape[0] != y.shape[0]:
        m = m[frames]
    if m.shape != y.shape:
        raise InputValueError(f"{spec}: model frames {m.shape[0]} do not match the capture's "
                              f"{y.shape[0]}")
    if not np.any(m):
        raise InputValueError(f"{spec}: the model ADC is all zeros (empty render)")
    return np.asarray(m), f"fitted render `{spec}`"


def cmd_residual(args) -> int:
    import os

    from tqdm import tqdm

    from ..captures.loader import load_capture
    from ..effects import EffectContext, EffectModel
    from ..residual import diagnose
    from ..residual.report import write_report

    if os.path.exists(args.out) and not args.overwrite:
        raise FileExistsError(f"{args.out}: a report is already there (use --overwrite)")
    if args.folds < 2:
        raise ConfigError(f"--folds must be >= 2, got {args.folds}")
    if args.max_rounds < 0:
        raise ConfigError(f"--max-rounds must be >= 0, got {args.max_rounds}")
    cap = load_capture(args.capture, calib_dir=args.calib_dir)
    frames = _frames(args.frames, cap.frames.shape[0])
    y = cap.frames[frames]
    base, source = base_model(args.model, cap, frames)
    ctx = EffectContext(cap.radar, num_frames=y.shape[0],
                        frame_period=float(cap.metadata.get("frame_period", 0.0) or 0.0))
    model = EffectModel(ctx, y, base)
    cands = candidate_effects(args.effects)
    bar = tqdm(desc="candidates", unit="fit", leave=False)
    d = diagnose(model, cands, folds=args.folds, max_rounds=args.max_rounds,
                 penalty=args.penalty, seed=args.seed, groups=args.fold_groups,
                 progress=lambda name: bar.update(1))
    bar.close()
    write_report(d, args.out, os.path.basename(str(args.capture)), source,
                 overwrite=args.overwrite)
    print(f"first fit: RA corr {d.first['ra_correlation']:.3f}, residual "
          f"{d.first['residual_energy_db']:.2f} dB")
    for a in d.adoptions:
        print(f"+ {a.name}: RA corr {a.after['ra_correlation']:.3f}, residual "
              f"{a.after['residual_energy_db']:.2f} dB")
    print(f"wrote {args.out}/")
    return 0
