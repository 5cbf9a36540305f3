"""``sionna-mmir residual``: find what a fitted model still gets wrong, and fix it.

Reads a capture (any format ``load_capture`` reads) and a *base model*
(:func:`sionna_mmir.residual.base_model.base_model`: an HDF5 render of the
fitted model, ``static`` or ``none``), diagnoses the residual with the
effects library (cross-validated ranking, adoption until nothing helps) and
writes the report folder (JSON, Markdown, PNGs; see
:mod:`sionna_mmir.residual.report`).
"""
from __future__ import annotations

from ..errors import ConfigError
from .args import FORMATTER, add_out, add_workers


def add_parser(sub) -> None:
    p = sub.add_parser("residual", help="diagnose a fit's residual with the effects library "
                                        "and report the error before and after",
                       formatter_class=FORMATTER)
    p.add_argument("capture", help="measured capture (TI .mat, DCA1000 .bin, ColoRadar run, HDF5)")
    p.add_argument("--model", required=True,
                   help="base model: HDF5 capture of the fitted render, 'static' (mean over "
                        "frames) or 'none'")
    add_out(p, "report folder", kind="folder")
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="frame range of multi-frame captures (default: all)")
    p.add_argument("--calib-dir", default=None, help="ColoRadar calib folder")
    p.add_argument("--effects", default=None,
                   help="comma-separated candidate effects (default: the whole library)")
    p.add_argument("--folds", type=int, default=3, help="cross-validation folds")
    p.add_argument("--fold-groups", choices=("auto", "channel", "cell"), default="auto",
                   help="cross-validation hold-out unit: whole virtual channels (auto: when "
                        "the array allows) or single (frame, Tx, Rx, chirp) cells")
    p.add_argument("--max-rounds", type=int, default=6, help="most adoptions")
    p.add_argument("--penalty", default="bic",
                   help="nats charged per parameter of a candidate: a number, or 'bic' for "
                        "ln(n)/2 with n the held-out samples (default)")
    p.add_argument("--seed", type=int, default=0, help="fold seed")
    add_workers(p)
    p.set_defaults(run=run)


def frame_slice(text, n: int) -> slice:
    """``A:B`` -> ``slice(A, B)`` inside ``0:n`` (``None``: all frames)."""
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


def run(args) -> int:
    import os

    from tqdm import tqdm

    from ..captures.loader import load_capture
    from ..effects import EffectContext, EffectModel
    from ..effects.library import candidate_effects
    from ..residual import diagnose
    from ..residual.base_model import base_model
    from ..residual.ranking import check_penalty
    from ..residual.workers import check_workers
    from ..residual.report import write_report

    if args.folds < 2:
        raise ConfigError(f"--folds must be >= 2, got {args.folds}")
    if args.max_rounds < 0:
        raise ConfigError(f"--max-rounds must be >= 0, got {args.max_rounds}")
    check_penalty(args.penalty)
    workers = check_workers(args.workers)
    cap = load_capture(args.capture, calib_dir=args.calib_dir)
    frames = frame_slice(args.frames, cap.frames.shape[0])
    y = cap.frames[frames]
    base, source = base_model(args.model, cap, frames)
    ctx = EffectContext(cap.radar, num_frames=y.shape[0],
                        frame_period=float(cap.metadata.get("frame_period", 0.0) or 0.0))
    model = EffectModel(ctx, y, base)
    cands = candidate_effects(args.effects)
    bar = tqdm(desc="candidates", unit="fit", leave=False)
    d = diagnose(model, cands, folds=args.folds, max_rounds=args.max_rounds,
                 penalty=args.penalty, seed=args.seed, groups=args.fold_groups,
                 progress=lambda name: bar.update(1), workers=workers)
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
