"""``sionna-mmir fit`` and ``sionna-mmir compare``: fit meshes to a capture.

``fit``      mmIR only: per-vertex materials, normals, beam patterns
``compare``  mmIR and the Sionna RT baseline, same loss / Adam / budget,
             Table 2 (Markdown + CSV), RA panels and loss curves

The work is :func:`sionna_mmir.compare.workflow.run_fit`; this module only
parses the command line.
"""
from __future__ import annotations

from ..paths.options import SolverOptions
from .args import (FORMATTER, add_capture, add_materials, add_out, add_pose, add_scaffold,
                   add_solver, mesh_names, named, pose, scaffold_options, solver_options)


def add_parser(sub) -> None:
    for name, helptext in (("fit", "fit per-vertex materials, normals and beam patterns of "
                                    "meshes to a capture (mmIR)"),
                           ("compare", "fit mmIR and the Sionna RT baseline to a capture and "
                                       "write Table 2 + pictures")):
        p = sub.add_parser(name, help=helptext, formatter_class=FORMATTER)
        add_capture(p)
        p.add_argument("meshes", nargs="+", help="PLY/OBJ meshes in the radar's scene frame "
                                                 "(object name = file stem)")
        add_out(p, "report folder", kind="folder")
        add_materials(p)
        add_pose(p)
        p.add_argument("--iterations", type=int, default=30, help="Adam steps per model")
        p.add_argument("--lr", type=float, default=0.05, help="Adam base step")
        add_solver(p, SolverOptions.fit())
        add_scaffold(p, "none")
        p.add_argument("--normals-smoothing", type=float, default=0.0,
                       help="lambda of the Laplacian parameterisation of the learned normals "
                            "(0: per-vertex; sionna_mmir.fit.smooth_param)")
        p.add_argument("--materials-smoothing", type=float, default=0.0,
                       help="the same for the per-vertex materials (0: off)")
        p.add_argument("--resume", action="store_true", help="continue from the checkpoint")
        if name == "compare":
            p.add_argument("--sionna-samples", type=int, default=20_000,
                           help="Sionna samples per source per iteration")
        p.set_defaults(run=run, with_sionna=name == "compare")


def run(args) -> int:
    from ..compare.workflow import FitRequest, run_fit

    position, orientation = pose(args)
    req = FitRequest(capture=args.capture, meshes=mesh_names(args.meshes), out=args.out,
                     materials=named(args.material, "--material", str), frame=args.frame,
                     calib_dir=args.calib_dir, position=position, orientation=orientation,
                     iterations=args.iterations, lr=args.lr, seed=args.seed,
                     solver=solver_options(args), scaffold=scaffold_options(args),
                     normals_smoothing=args.normals_smoothing,
                     materials_smoothing=args.materials_smoothing,
                     with_sionna=args.with_sionna,
                     sionna_samples=getattr(args, "sionna_samples", 20_000),
                     resume=args.resume, overwrite=args.overwrite)
    summary = run_fit(req)
    for k, v in summary.items():
        print(f"{k}: RA correlation {v['metrics_before']['ra_correlation']:.3f} -> "
              f"{v['metrics_after']['ra_correlation']:.3f}, "
              f"{v['seconds_per_iteration']:.2f} s/iteration")
    print(f"wrote {args.out}/")
    return 0
