"""Write the independent undeclared-effect suite as ColoRadar run folders.

Usage::

    python benchmarks/make_undeclared_suite.py OUT_DIR [--subset full|fast] [--seed N]
        [--snr-db DB] [--frames F] [--quantize]

Creates ``OUT_DIR/<NN>_<case>/`` (see
:func:`sionna_mmir.independent.undeclared.write_coloradar_run`) for every case
of :func:`~sionna_mmir.independent.undeclared.suite` and ``OUT_DIR/index.json``
listing, per case, its folder, effects, sensor, ADC shape and generation time.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))   # this checkout's package
from sionna_mmir.independent import undeclared as und  # noqa: E402


def _folder_name(index: int, name: str) -> str:
    return f"{index:02d}_" + name.replace(":", "_").replace("+", "__")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", type=pathlib.Path)
    ap.add_argument("--subset", choices=("full", "fast"), default="full")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--snr-db", type=float, default=35.0)
    ap.add_argument("--frames", type=int, default=1)
    ap.add_argument("--quantize", action="store_true")
    args = ap.parse_args(argv)
    out = args.out_dir
    out.mkdir(parents=True, exist_ok=True)
    sensor = "single_chip" if args.subset == "fast" else "cascade"
    cases = und.iter_suite(args.subset, args.seed, snr_db=args.snr_db, num_frames=args.frames,
                           quantize=args.quantize)
    rows, t_all = [], time.perf_counter()
    for i in range(len(und.suite_kinds(args.subset))):
        t0 = time.perf_counter()
        case = next(cases)
        dt = time.perf_counter() - t0
        folder = _folder_name(i, case.name)
        und.write_coloradar_run(case, out / folder, overwrite=True)
        rows.append({"name": case.name, "folder": folder, "effects": list(case.effects),
                     "sensor": sensor, "seed": case.seed,
                     "shape": list(case.capture.frames.shape), "generation_s": round(dt, 3)})
        print(f"{folder:45s} {dt:7.2f} s", flush=True)
    total = time.perf_counter() - t_all
    index = {"generator": "sionna_mmir.independent.undeclared", "subset": args.subset,
             "seed": args.seed, "snr_db": args.snr_db, "frames": args.frames,
             "quantize": args.quantize,
             "library_effects": list(und.LIBRARY_EFFECTS),
             "outside_effects": list(und.OUTSIDE_EFFECTS), "total_s": round(total, 2),
             "cases": rows}
    (out / "index.json").write_text(json.dumps(index, indent=1))
    print(f"{len(rows)} cases in {total:.1f} s -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
