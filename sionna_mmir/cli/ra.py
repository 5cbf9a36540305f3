"""``sionna-mmir ra``: range-azimuth picture of a capture (frames averaged)."""
from __future__ import annotations

import pathlib

from ..errors import FrameIndexError
from .args import FORMATTER, add_capture, add_out, positive


def add_parser(sub) -> None:
    p = sub.add_parser("ra", help="range-azimuth picture(s) of a capture",
                       formatter_class=FORMATTER)
    add_capture(p)
    add_out(p, "output PNG")
    p.add_argument("--frames", type=int, default=1, help="number of frames to average "
                   "non-coherently from --frame on (progress bar)")
    p.add_argument("--cartesian", action="store_true", help="x/y picture instead of range/angle")
    p.add_argument("--doppler", default="mean", choices=["mean", "noncoherent"],
                   help="how chirps are combined")
    p.set_defaults(run=run)


def run(args) -> int:
    from tqdm import tqdm

    from ..captures.loader import load_capture
    from ..plotting import save_ra_panels
    from ..processing.imaging import range_azimuth

    positive(args.frames, "--frames")
    cap = load_capture(args.capture, calib_dir=args.calib_dir, sensor=args.sensor)
    first = args.frame or 0
    last = min(cap.num_frames, first + args.frames)
    if not 0 <= first < cap.num_frames:
        raise FrameIndexError(f"{args.capture}: frame {first} requested, the capture has "
                              f"{cap.num_frames} frame(s)")
    acc = None
    for f in tqdm(range(first, last), desc="RA frames", unit="frame", disable=last - first < 2):
        ra, ranges, az = range_azimuth(cap.frames[f], cap.radar, doppler=args.doppler)
        acc = ra if acc is None else acc + ra
    save_ra_panels({f"{pathlib.Path(args.capture).name} frames {first}-{last - 1}": acc},
                   ranges, az, args.out, cartesian=args.cartesian)
    print(f"wrote {args.out}")
    return 0
