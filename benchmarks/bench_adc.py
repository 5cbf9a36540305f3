"""ADC-synthesis benchmark: sionna_mmir's factorised product vs plain NumPy.

Cascade radar (12 Tx x 16 Rx = 192 pairs), 256 samples, 16 chirps, random
paths with exact per-pair delays.  "path-samples" = pairs x chirps x samples
x paths.  The NumPy reference is the package's reference twin
(``synthesize_adc_basic``: a dense ``exp`` per pair, one chirp when static),
measured in the same run on the same inputs; its Doppler case is only run up
to 1e3 paths (it takes minutes beyond).

A second table runs one static chirp side by side with Sionna RT's own
``Paths.cfr`` (the same sum, ``conj`` convention) on the same paths.

Run:  python benchmarks/bench_adc.py [--paths 1000 10000 100000] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from sionna_mmir import RadarConfig
from sionna_mmir.fmcw import synthesize_adc, synthesize_adc_basic


def _time(fn, repeat=3):
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def run(paths=(1000, 10000, 100000), reference_limit=(10000, 1000), repeat=3):
    radar = RadarConfig.mmwcas(num_chirps=16)
    rng = np.random.default_rng(0)
    rows = []
    for P in paths:
        shape = (radar.num_tx, radar.num_rx, P)
        a = (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64)
        tau = rng.uniform(1e-9, 1e-7, size=shape)
        rho = rng.uniform(-1e-7, 1e-7, size=shape)
        n = radar.num_tx * radar.num_rx * radar.num_chirps * radar.num_samples * P
        for moving, limit in ((False, reference_limit[0]), (True, reference_limit[1])):
            tr = rho if moving else None
            rep = 1 if P >= 100000 else repeat
            t_fast = _time(lambda: synthesize_adc(radar, a, tau, tr), rep)
            t_ref = _time(lambda: synthesize_adc_basic(radar, a, tau, tr), 1) if P <= limit else None
            rows.append(dict(paths=P, doppler=moving, fast_s=t_fast, fast_rate=n / t_fast,
                             numpy_s=t_ref, numpy_rate=None if t_ref is None else n / t_ref,
                             speedup=None if t_ref is None else t_ref / t_fast))
    return rows


def run_vs_sionna(paths=(1000, 10000), repeat=3):
    """One static chirp, same a / tau: sionna_mmir vs Sionna RT's ``Paths.cfr``.

    Sionna's method runs unmodified through :mod:`sionna_cfr`'s adapter
    (Dr.Jit LLVM, warmed up first so JIT compilation is not timed).
    """
    import sionna_mmir
    from sionna_cfr import sionna_beat_signal

    sionna_mmir.init_backend()
    radar = RadarConfig.mmwcas(num_chirps=1)
    rng = np.random.default_rng(1)
    rows = []
    for P in paths:
        shape = (radar.num_tx, radar.num_rx, P)
        a = rng.normal(size=shape) + 1j * rng.normal(size=shape)
        tau = rng.uniform(1e-9, 1e-7, size=shape)
        sionna_beat_signal(radar, a, tau)                       # warm-up (JIT)
        t_rt = _time(lambda: sionna_beat_signal(radar, a, tau), repeat)
        t_mm = _time(lambda: synthesize_adc(radar, a, tau), repeat)
        n = radar.num_tx * radar.num_rx * radar.num_samples * P
        rows.append(dict(paths=P, sionna_s=t_rt, mmir_s=t_mm, ratio=t_mm / t_rt,
                         mmir_rate=n / t_mm, sionna_rate=n / t_rt))
    return rows


def to_markdown_vs_sionna(rows):
    out = ["| paths | sionna_mmir [s] | Sionna RT `Paths.cfr` [s] | time ratio mmIR / Sionna |",
           "|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['paths']:.0e} | {r['mmir_s']:.3f} | {r['sionna_s']:.3f} | {r['ratio']:.2f} |")
    return "\n".join(out)


def to_markdown(rows):
    out = ["| paths | Doppler | sionna_mmir [s] | path-samples/s | NumPy reference [s] | path-samples/s | speed-up |",
           "|---:|:---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        ref = "-" if r["numpy_s"] is None else f"{r['numpy_s']:.2f}"
        rr = "-" if r["numpy_rate"] is None else f"{r['numpy_rate']:.2e}"
        sp = "-" if r["speedup"] is None else f"{r['speedup']:.0f}x"
        out.append(f"| {r['paths']:.0e} | {'yes' if r['doppler'] else 'no'} | {r['fast_s']:.3f} | "
                   f"{r['fast_rate']:.2e} | {ref} | {rr} | {sp} |")
    return "\n".join(out)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--paths", type=int, nargs="+", default=[1000, 10000, 100000])
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    rows = run(tuple(args.paths))
    vs = run_vs_sionna(tuple(p for p in args.paths if p <= 10000))
    print(to_markdown(rows))
    print()
    print(to_markdown_vs_sionna(vs))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"numpy": rows, "sionna": vs}, f, indent=1)


if __name__ == "__main__":
    main()
