"""``sionna-mmir info``: summarise a capture (radar, shapes, strongest return)."""
from __future__ import annotations

import numpy as np

from ..errors import SionnaMMIRError
from .args import FORMATTER, add_capture, waveform


def add_parser(sub) -> None:
    p = sub.add_parser("info", help="summarise a capture (radar, shapes, strongest return)",
                       formatter_class=FORMATTER)
    add_capture(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from ..captures.loader import load_capture
    from ..processing.detection import classify_peaks, find_target, search_start
    from ..processing.imaging import range_azimuth

    cap = load_capture(args.capture, frame=args.frame, calib_dir=args.calib_dir,
                       sensor=args.sensor,
                       waveform=waveform(args))
    r = cap.radar
    ra, ranges, az = range_azimuth(cap.adc, r)
    start = search_start(r, 0.5)
    try:
        r_peak, az_peak, peaks = find_target(cap.adc, r, r_min=0.5)
    except SionnaMMIRError:
        r_peak, az_peak, peaks = float("nan"), float("nan"), classify_peaks(cap.adc, r, 0.5)
    print(f"source        {cap.source}")
    print(f"radar         {r.name}: {r.num_tx} tx x {r.num_rx} rx, {r.num_chirps} chirps x "
          f"{r.num_samples} samples")
    print(f"waveform      f0 {r.start_frequency / 1e9:.4f} GHz, slope {r.slope / 1e12:.3f} MHz/us, "
          f"fs {r.sample_rate / 1e6:.3f} Msps")
    print(f"range         resolution {r.range_resolution * 100:.2f} cm, max {r.max_range:.2f} m")
    print(f"frames        {cap.num_frames}")
    print(f"strongest     {r_peak:.3f} m, {np.degrees(az_peak):+.1f} deg (beyond {start:.2f} m: "
          f"past the Tx-Rx leakage; interference rejected)")
    tones = [p for p in peaks if p["interference"]]
    if tones:
        print("interference  " + ", ".join(f"{p['range']:.2f} m" for p in tones)
              + " (comb / aligned across channels / not persistent)")
    return 0
