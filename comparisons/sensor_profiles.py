"""Leave-one-capture-out test of sensor profiles on the MMWCAS corner captures (one command).

    .venv/bin/python comparisons/sensor_profiles.py [--iterations N]

For each ordered pair (A, B) of ``corner_4m7_slope79.mat`` and
``corner_6m1_slope79.mat`` (from ``../shared/data/measured/mmwcas_corner/``
or ``$SIONNA_MMIR_MEASURED``): ``calibrate_profile([A])`` (what
``sionna-mmir calibrate A --out P.h5`` does), then on B, with the profile
frozen: a point-target scene (NumPy, :func:`fit_scene`), and the
corner-reflector scene fitted by mmIR and by Sionna RT through the same
profile (:class:`~sionna_mmir.fit.profiled.ProfiledModel`), and the same two
fits without a profile.  RA correlation before / after the fit and the
complex residual ``|d - m|^2 / |d|^2`` [dB] with the best scene scale.
The ceiling line puts A's *measured* near-range content (leakage) into B's
own capture: what a perfect scene and a perfect copy of A's leakage would reach.
Writes ``sensor_profiles.{md,json}``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
CAPTURES = ("corner_4m7_slope79.mat", "corner_6m1_slope79.mat")


def _residual(side, model, cap, profile):
    from sionna_mmir.effects.profile import residual_db
    from sionna_mmir.paths.render import to_numpy

    inner = getattr(model, "model", model)
    x = to_numpy(inner.render(side.extra["latents"], seed=9001)[0])
    if getattr(model, "arrival", None) is not None:
        x = x * model.arrival[:, :, None, None]
    d = cap.adc
    if profile is None:
        s = np.vdot(x, d) / max(np.vdot(x, x).real, 1e-30)
        return residual_db(d, s * x)
    return residual_db(d, profile.apply(x, cap.radar, profile.scene_scale(x, d, cap.radar)))


def _ceiling(cap_b, cap_a, bins=8):
    """RA corr and residual of B's capture with its near-range bins replaced by A's."""
    from sionna_mmir.effects.profile import residual_db
    from sionna_mmir.metrics.ra import pearson
    from sionna_mmir.processing.imaging import range_azimuth

    def near(x):
        spec = np.fft.fft(x, axis=-1)
        spec[..., bins:-bins] = 0
        return np.fft.ifft(spec, axis=-1)

    m = cap_b.adc - near(cap_b.adc) + near(cap_a.adc)
    ra = range_azimuth(cap_b.adc, cap_b.radar)[0]
    return pearson(ra, range_azimuth(m, cap_b.radar)[0]), residual_db(cap_b.adc, m)


def evaluate(cap_b, profile, iterations, sionna_samples):
    """Rows for capture B with ``profile`` (or None)."""
    from sionna_mmir.compare.corner_scene import fit_corner_scene
    from sionna_mmir.effects.sensor_calibration import fit_scene
    from sionna_mmir.metrics.ra import pearson
    from sionna_mmir.processing.imaging import range_azimuth
    from sionna_mmir.processing.detection import find_target
    from sionna_mmir.fmcw.targets import refine_point_target
    from sionna_mmir.processing.virtual_array import VirtualArray

    radar = cap_b.radar
    ra = range_azimuth(cap_b.adc, radar)[0]
    rows = []
    if profile is not None:
        f = fit_scene(cap_b, profile)
        rows.append({"model": "point target (NumPy)", "ra_before": None,
                     "ra_after": pearson(ra, range_azimuth(f["model"][:, :, None], radar)[0]),
                     "residual_db": f["residual_db"]})
        r, az_deg, centre, arrival = f["range_m"], f["azimuth_deg"], f["origin"], f["arrival"]
    else:
        centre = VirtualArray(radar).phase_centre()
        r0, az0, _ = find_target(cap_b.adc, radar)
        r, az_deg = refine_point_target(cap_b.adc, radar, r0, np.degrees(az0), centre)
        arrival = None
    sides = fit_corner_scene(cap_b, ra, r, np.radians(az_deg), centre, iterations=iterations,
                             progress=False, sensor_profile=profile, arrival=arrival,
                             sionna_samples=sionna_samples)
    models = {}
    for label, side in sides.items():
        rows.append({"model": label, "ra_before": side.metrics_before["ra_correlation"],
                     "ra_after": side.metrics_after["ra_correlation"],
                     "residual_db": _residual(side, side.extra["model"], cap_b, profile)})
        models[label] = side
    return rows, sides


HEADER = """# Sensor profiles, leave one capture out

**Reproduce:** `python comparisons/sensor_profiles.py` (writes this file and
`sensor_profiles.json`; needs `../shared/data/measured/`).  **Truth: the
measured capture** (TI MMWCAS cascade; the profile is calibrated on the
*other* capture and applied frozen: gains, delays and leakage are not refitted).

RA corr: Pearson correlation of the range-azimuth maps before / after the
scene fit (10 Adam iterations, same loss and budget for mmIR and Sionna RT;
Sionna RT with {samples} samples per source).  Residual: ``|d - m|^2 / |d|^2``
of the chirp-averaged complex ADC with the best scene scale [dB] (0 dB: the
model explains nothing; today's first fit of corner_6m1 is at -0.00 dB).
"point target" is the scene fit under the profile in NumPy (range,
direction, an Rx-side arrival ramp, amplitude); "ceiling" replaces B's own
near-range bins (leakage) by A's measured ones in B's capture: what a
perfect scene and an exact copy of A's leakage would reach.

| capture B | profile from A | model | RA corr before | RA corr after | residual [dB] |
|---|---|---|---|---|---|
"""


def _fmt(v):
    return "" if v is None else f"{v:.3f}" if abs(v) < 10 else f"{v:.2f}"


def write_markdown(rows, path, samples) -> None:
    """The table of :func:`main`'s rows."""
    lines = [HEADER.format(samples=samples)]
    for r in rows:
        lines.append(f"| {r['capture']} | {r['profile']} | {r['model']} | {_fmt(r['ra_before'])} | "
                     f"{_fmt(r['ra_after'])} | {_fmt(r['residual_db'])} |\n")
    with open(path, "w") as f:
        f.write("".join(lines))


def main(argv=None) -> int:
    from sionna_mmir.captures.loader import load_capture
    from sionna_mmir.captures.measured import find_measured_dir
    from sionna_mmir.effects.sensor_calibration import calibrate_profile

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--iterations", type=int, default=10)
    p.add_argument("--out", default=HERE)
    p.add_argument("--sionna-samples", type=int, default=50_000,
                   help="Sionna RT samples per source and iteration (memory)")
    args = p.parse_args(argv)
    measured = find_measured_dir()
    if measured is None:
        print("measured data not found (../shared/data/measured); nothing to do")
        return 1
    caps = {n: load_capture(measured / "mmwcas_corner" / n) for n in CAPTURES}
    out = []
    for a, b in (CAPTURES, CAPTURES[::-1]):
        profile = calibrate_profile([caps[a]], names=[a])
        for prof, label in ((None, "none"), (profile, a.split("_slope")[0])):
            rows, _ = evaluate(caps[b], prof, args.iterations, args.sionna_samples)
            for row in rows:
                row.update(capture=b.split("_slope")[0], profile=label)
                out.append(row)
                print(json.dumps(row, default=float), flush=True)
        ra_c, res_c = _ceiling(caps[b], caps[a])
        out.append({"capture": b.split("_slope")[0], "profile": a.split("_slope")[0],
                    "model": "ceiling: measured leakage of the other capture", "ra_before": None,
                    "ra_after": ra_c, "residual_db": res_c})
        print(json.dumps(out[-1], default=float), flush=True)
    with open(os.path.join(args.out, "sensor_profiles.json"), "w") as f:
        json.dump(out, f, indent=1, default=float)
    write_markdown(out, os.path.join(args.out, "sensor_profiles.md"), args.sionna_samples)
    return 0


if __name__ == "__main__":
    sys.exit(main())
