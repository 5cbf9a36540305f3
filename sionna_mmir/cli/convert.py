"""``sionna-mmir convert``: any readable capture -> the sionna_mmir HDF5 format."""
from __future__ import annotations

from .args import FORMATTER, add_capture, add_out


def add_parser(sub) -> None:
    p = sub.add_parser("convert", help="convert a capture to the sionna_mmir HDF5 format",
                       formatter_class=FORMATTER)
    add_capture(p)
    add_out(p, "output .h5 capture")
    p.set_defaults(run=run)


def run(args) -> int:
    from ..captures.loader import load_capture

    cap = load_capture(args.capture, frame=args.frame, calib_dir=args.calib_dir,
                       sensor=args.sensor)
    cap.save(args.out, overwrite=args.overwrite)
    print(f"wrote {args.out} ({cap.num_frames} frame(s), {cap.radar.adc_shape})")
    return 0
