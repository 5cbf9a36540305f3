"""``sionna-mmir demo``: the main job (:func:`sionna_mmir.compare.demo.run_demo`)."""
from __future__ import annotations

import json

from .args import FORMATTER, add_out


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help="run the main job (signal-chain demo on the measured "
                                    "corner capture, or an embedded synthetic one)",
                       formatter_class=FORMATTER)
    p.add_argument("--capture", default=None, help="capture to use (default: "
                   "../shared/data/measured/mmwcas_corner/corner_4m7_slope79.mat if found)")
    add_out(p, "report folder", required=False, default="sionna_mmir_demo", kind="folder")
    p.add_argument("--iterations", type=int, default=6,
                   help="fit iterations per model in the inverse-rendering stage (0: skip)")
    p.set_defaults(run=run)


def run(args) -> int:
    from ..compare.demo import run_demo
    from .args import positive

    positive(args.iterations, "--iterations", minimum=0)
    summary = run_demo(capture=args.capture, out=args.out, overwrite=args.overwrite,
                       fit_iterations=args.iterations)
    short = {k: v for k, v in summary.items() if k != "fit"}
    short["fit"] = {k: {"ra_correlation_before": v["metrics_before"]["ra_correlation"],
                        "ra_correlation_after": v["metrics_after"]["ra_correlation"],
                        "seconds_per_iteration": v["seconds_per_iteration"]}
                    for k, v in summary.get("fit", {}).items()}
    print(json.dumps(short, indent=1, default=float))
    return 0
