"""``sionna-mmir render``: meshes + radar -> rendered raw ADC in an HDF5 capture.

The radar is a preset (``--radar``) or the radar of a capture
(``--radar-from CAPTURE``: its waveform, layout and chirps, so that the
render is a base model for that capture); ``--position`` / ``--orientation``
place it in the meshes' frame.
"""
from __future__ import annotations

import dataclasses

from ..paths.options import SolverOptions
from ..radar.config import RadarConfig
from .args import (FORMATTER, add_materials, add_out, add_pose, add_solver, mesh_names, named,
                   noise_db, pose, positive, solver_options, speed, triple)


def add_parser(sub) -> None:
    p = sub.add_parser("render", help="render raw ADC of PLY/OBJ meshes into an HDF5 capture",
                       formatter_class=FORMATTER)
    p.add_argument("meshes", nargs="+", help="PLY/OBJ files; each is one object named by its "
                                             "file stem, in the radar's scene frame")
    add_out(p, "output .h5 capture")
    add_materials(p)
    radar = p.add_mutually_exclusive_group()
    radar.add_argument("--radar", default="mmwcas", choices=list(RadarConfig.PRESETS),
                       help="radar preset")
    radar.add_argument("--radar-from", default=None, metavar="CAPTURE",
                       help="use the radar (waveform, layout, chirps) of this capture")
    p.add_argument("--calib-dir", default=None, help="ColoRadar calib folder for --radar-from")
    add_pose(p)
    p.add_argument("--chirps", type=int, default=None,
                   help="chirp loops per frame (default: the radar's)")
    p.add_argument("--frames", type=int, default=1, help="frames (new seed each; progress bar)")
    add_solver(p, SolverOptions(num_rays=50_000), fields=("rays", "depth", "sampling", "cone",
                                                          "min_rel_power", "seed", "diffraction"))
    p.add_argument("--velocity", action="append", metavar="OBJECT=VX,VY,VZ",
                   help="object velocity [m/s] (Doppler); repeatable")
    p.add_argument("--noise-db", type=float, default=None,
                   help="receiver noise power per ADC sample relative to the peak sample [dB]")
    p.set_defaults(run=run)


def _radar(args):
    position, orientation = pose(args)
    if args.radar_from is not None:
        from ..captures.loader import load_capture

        radar = load_capture(args.radar_from, frame=0, calib_dir=args.calib_dir).radar
    else:
        radar = RadarConfig.preset(args.radar)
    changes = {"position": position, "orientation": orientation}
    if args.chirps is not None:
        changes["num_chirps"] = args.chirps
    return dataclasses.replace(radar, **changes)


def check_size(radar, frames: int) -> None:
    """Refuse a render whose frames exceed the machine's memory (before rendering)."""
    from ..utils.memory import array_bytes, check_memory, format_bytes
    from .synth import WORK_FACTOR

    adc = array_bytes((frames, *radar.adc_shape), 8)
    check_memory(WORK_FACTOR * adc, f"--frames {frames} --chirps {radar.num_chirps}: "
                                    f"{frames} frame(s) of {' x '.join(map(str, radar.adc_shape))} "
                                    f"[tx, rx, chirp, sample] ({format_bytes(adc)} as complex64)")


def run(args) -> int:
    from ..paths.render import render_capture
    from ..scene import load_scene

    positive(args.frames, "--frames")
    noise_db(args.noise_db)
    names = mesh_names(args.meshes)
    materials = named(args.material, "--material", str)
    velocities = named(args.velocity, "--velocity",
                       lambda v: speed(triple(v, "--velocity"), f"--velocity {v}"))
    options = solver_options(args, velocities=velocities or None)
    radar = _radar(args)
    check_size(radar, args.frames)
    scene = load_scene(names, materials=materials, radar=radar)
    cap = render_capture(scene, radar, options, frames=args.frames, noise_db=args.noise_db,
                         metadata={"meshes": names, "materials": materials},
                         progress=args.frames > 1)
    cap.save(args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}: {cap.num_frames} frame(s) of {cap.frames.shape[1:]} "
          f"[tx, rx, chirp, sample], {cap.metadata['hits'][0]} ray hits in frame 0")
    return 0
