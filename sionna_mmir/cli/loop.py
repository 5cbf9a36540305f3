"""``sionna-mmir loop``: fit -> diagnose -> adopt -> joint refit -> report, in one command.

The work is :func:`sionna_mmir.pipeline.run_loop`; this module only parses.
"""
from __future__ import annotations

from ..pipeline.radar_model import loop_solver_options
from .args import (FORMATTER, add_capture, add_materials, add_out, add_sensor_profile, add_solver,
                   mesh_names, named, pose, solver_options, waveform, add_workers)


def add_parser(sub) -> None:
    p = sub.add_parser("loop", help="close the loop: fit the scene, diagnose the residual "
                                    "(scene mismatch before sensor effects), adopt, refit "
                                    "jointly, report", formatter_class=FORMATTER)
    add_capture(p)
    p.add_argument("meshes", nargs="*", help="PLY/OBJ meshes in the radar's scene frame "
                                             "(object name = file stem)")
    add_out(p, "report folder", kind="folder")
    p.add_argument("--scene", default="meshes", choices=["meshes", "corner"],
                   help="the meshes given, or (corner-reflector captures without a mesh) a "
                        "trihedral and a floor at the detected corner")
    add_materials(p)
    p.add_argument("--position", default=None,
                   help="radar position x,y,z [m] in the meshes' frame (default: the run's "
                        "calib/transforms, else the origin)")
    p.add_argument("--orientation", default=None,
                   help="radar yaw,pitch,roll [deg] (default: the run's transforms, else 0)")
    p.add_argument("--fit-iterations", type=int, default=10,
                   help="Adam steps of the range-azimuth fit of materials and beams (0: none)")
    p.add_argument("--lr", type=float, default=0.05, help="Adam base step")
    add_solver(p, loop_solver_options(), fields=("rays", "depth", "sampling", "min_rel_power",
                                                 "seed"))
    p.add_argument("--effects", default=None,
                   help="comma-separated candidate effects (default: the whole library and "
                        "the scene-side refinements)")
    p.add_argument("--folds", type=int, default=3, help="cross-validation folds")
    p.add_argument("--penalty", default="bic",
                   help="nats charged per parameter of a candidate: a number, or 'bic' for "
                        "ln(n)/2 with n the held-out samples (default)")
    p.add_argument("--resume", action="store_true", help="continue a killed run")
    add_workers(p)
    add_sensor_profile(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from ..pipeline import LoopRequest, run_loop

    position = orientation = None
    if args.position is not None or args.orientation is not None:
        args.position = args.position or "0,0,0"
        args.orientation = args.orientation or "0,0,0"
        position, orientation = pose(args)
    req = LoopRequest(capture=args.capture, out=args.out, meshes=mesh_names(args.meshes),
                      scene=args.scene, materials=named(args.material, "--material", str),
                      frame=args.frame, calib_dir=args.calib_dir, sensor=args.sensor,
                      position=position, orientation=orientation,
                      fit_iterations=args.fit_iterations, lr=args.lr, seed=args.seed,
                      solver=solver_options(args), effects=args.effects, folds=args.folds,
                      penalty=args.penalty, resume=args.resume, overwrite=args.overwrite,
                      waveform=waveform(args), sensor_profile=args.sensor_profile,
                      workers=args.workers)
    doc = run_loop(req)
    print(f"first: RA corr {doc['first']['ra_correlation']:.3f}, residual "
          f"{doc['first']['residual_energy_db']:.2f} dB")
    for a in doc["adoptions"]:
        print(f"+ {a['name']} ({a['side']}): RA corr {a['after']['ra_correlation']:.3f}, "
              f"residual {a['after']['residual_energy_db']:.2f} dB")
    print(f"stopped: {doc['stop_reason']}; wrote {args.out}/")
    return 0
