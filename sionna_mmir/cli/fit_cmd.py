"""``sionna-mmir fit`` and ``sionna-mmir compare``: fit meshes to a capture.

``fit``      mmIR only: per-vertex materials, normals, beam patterns
``compare``  mmIR and the Sionna RT baseline, same loss / Adam / budget,
             Table 2 (Markdown + CSV), RA panels and loss curves

Both read any capture ``load_capture`` reads (TI ``.mat``, DCA1000 ``.bin``,
ColoRadar run folder + ``--frame``, HDF5) and PLY/OBJ meshes placed in the
radar's scene frame (``--position`` / ``--orientation`` give the radar pose),
and write into a report folder: ``summary.json``, ``report.md``, PNGs and the
fit checkpoint(s) ``fit_*.h5`` (``--resume`` continues a killed fit) and the
fitted models' renders ``model_*.h5`` (the input of ``sionna-mmir residual``).
"""
from __future__ import annotations

import json
import os
import shutil

import numpy as np

from ..errors import ConfigError, InputValueError
from .render_cmd import _named, _triple


def add_parsers(sub) -> None:
    for name, helptext in (("fit", "fit per-vertex materials, normals and beam patterns of "
                                    "meshes to a capture (mmIR)"),
                           ("compare", "fit mmIR and the Sionna RT baseline to a capture and "
                                       "write Table 2 + pictures")):
        p = sub.add_parser(name, help=helptext)
        p.add_argument("capture", help="capture (TI .mat, DCA1000 .bin, ColoRadar run, HDF5)")
        p.add_argument("meshes", nargs="+", help="PLY/OBJ meshes (object name = file stem)")
        p.add_argument("--out", required=True, help="report folder")
        p.add_argument("--frame", type=int, default=None, help="frame index")
        p.add_argument("--calib-dir", default=None, help="ColoRadar calib folder")
        p.add_argument("--material", action="append", metavar="OBJECT=ITU",
                       help="initial ITU-R P.2040 material per object (default concrete)")
        p.add_argument("--position", default="0,0,0", help="radar position x,y,z [m]")
        p.add_argument("--orientation", default="0,0,0", help="radar yaw,pitch,roll [deg]")
        p.add_argument("--iterations", type=int, default=30)
        p.add_argument("--lr", type=float, default=0.05)
        p.add_argument("--rays", type=int, default=20_000, help="mmIR rays per iteration")
        p.add_argument("--depth", type=int, default=2)
        p.add_argument("--sampling", default="random", choices=["random", "facets"],
                       help="mmIR path sampling (facets: deterministic per-facet quadrature)")
        p.add_argument("--denoise", action="store_true",
                       help="denoise the meshes first (LiDAR scans; scene/denoise.py, "
                            "radius 3 median edge lengths); both models get the result")
        p.add_argument("--planes", action="store_true",
                       help="snap planar regions onto fitted planes (after --denoise; "
                            "sionna_mmir.scene.snap_planes)")
        p.add_argument("--shading", default="shared", choices=["shared", "flat", "auto"],
                       help="shading normals: the meshes' shared vertices, flat (every face "
                            "its own normal), or auto (curved objects crease-split, the others "
                            "flat; sionna_mmir.scene.auto_shaded)")
        p.add_argument("--flat-shading", action="store_true", help="same as --shading flat")
        p.add_argument("--min-rel-power", type=float, default=1e-6,
                       help="drop paths weaker than this x the strongest in the solver, before "
                            "their per-element legs and the ADC synthesis (1e-6: facet fits ~3x "
                            "faster than at 1e-8, RA maps unchanged to ~1e-3; the benchmark "
                            "table uses 1e-5; 0 keeps all)")
        p.add_argument("--normals-smoothing", type=float, default=0.0,
                       help="lambda of the Laplacian parameterisation of the learned normals "
                            "(0: per-vertex; sionna_mmir.fit.smooth_param)")
        p.add_argument("--materials-smoothing", type=float, default=0.0,
                       help="the same for the per-vertex materials (a spatial smoothness "
                            "prior; 0: off)")
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--resume", action="store_true", help="continue from the checkpoint")
        p.add_argument("--overwrite", action="store_true", help="replace an existing report")
        if name == "compare":
            p.add_argument("--sionna-samples", type=int, default=20_000,
                           help="Sionna samples per source per iteration")


def _setup(args):
    from ..captures.loader import load_capture
    from ..scene import load_scene

    if os.path.exists(args.out) and not (args.overwrite or args.resume):
        raise FileExistsError(f"{args.out}: report folder exists (use --overwrite or --resume)")
    if args.iterations < 1:
        raise ConfigError(f"--iterations must be >= 1, got {args.iterations}")
    cap = load_capture(args.capture, frame=args.frame, calib_dir=args.calib_dir)
    frames = cap.frames
    if not np.isfinite(frames.real).all() or not np.isfinite(frames.imag).all():
        raise InputValueError(f"{args.capture}: capture holds NaN or Inf samples")
    radar = _posed(cap.radar, args)
    names = {}
    for path in args.meshes:
        names[os.path.splitext(os.path.basename(path))[0].replace(".", "_")] = path
    mats = _named(args.material, "--material", str)
    shading = "flat" if getattr(args, "flat_shading", False) else getattr(args, "shading", "shared")
    denoise, planes = getattr(args, "denoise", False), getattr(args, "planes", False)
    if denoise or planes or shading != "shared":
        from ..scene import prepare_scaffold

        names = prepare_scaffold(_read(names), denoise=denoise, planes=planes, shading=shading)
    scene = load_scene(names, materials=mats, radar=radar)
    return cap, radar, names, mats, scene


def _read(paths: dict) -> dict:
    """name -> ``trimesh.Trimesh`` of validated mesh files."""
    import trimesh

    from ..scene import read_mesh

    meshes = {}
    for name, path in paths.items():
        data = read_mesh(path)
        meshes[name] = trimesh.Trimesh(data.vertices, data.faces, process=False)
    return meshes


def _posed(radar, args):
    import dataclasses

    return dataclasses.replace(radar, position=_triple(args.position, "--position"),
                               orientation=tuple(np.radians(_triple(args.orientation,
                                                                    "--orientation"))))


def _check_overlap(model, where):
    adc, _ = model.render(model.latents(), seed=12345)
    from ..paths.render import to_numpy

    if not np.any(to_numpy(adc)):
        raise InputValueError(f"{where}: the meshes and the capture do not overlap: no ray "
                              "from the radar hits the meshes (check --position / "
                              "--orientation and the mesh coordinates)")


def _run(args, with_sionna: bool) -> int:
    from ..compare.harness import target_ra
    from ..fit import MMIRModel, SionnaModel

    cap, radar, names, mats, scene = _setup(args)
    ra_ref = target_ra(cap.frames, radar)
    mm = MMIRModel(scene, solver_options=dict(num_rays=args.rays, max_depth=args.depth,
                                              sampling=args.sampling),
                   min_rel_power=args.min_rel_power, normals_smoothing=args.normals_smoothing,
                   materials_smoothing=args.materials_smoothing)
    _check_overlap(mm, args.capture)
    models = [("mmIR", mm)]
    if with_sionna:
        from ..baseline import SionnaBaseline

        models.append(("Sionna RT", SionnaModel(SionnaBaseline(
            names, {k: mats.get(k, "concrete") for k in names}, radar,
            samples_per_src=args.sionna_samples))))
    # work in <out>.partial; a killed fit leaves its checkpoints there for --resume
    tmp = args.out + ".partial"
    if os.path.exists(tmp) and not args.resume:
        shutil.rmtree(tmp)
    os.makedirs(tmp, exist_ok=True)
    if args.resume and os.path.isdir(args.out):
        for f in os.listdir(args.out):
            if f.endswith(".h5") and not os.path.exists(os.path.join(tmp, f)):
                shutil.copy(os.path.join(args.out, f), os.path.join(tmp, f))
    try:
        return _fit_and_report(args, cap, radar, names, models, ra_ref, tmp)
    except Exception:
        if not args.resume:
            shutil.rmtree(tmp, ignore_errors=True)
        raise


def _fit_and_report(args, cap, radar, names, models, ra_ref, tmp) -> int:
    from ..compare.harness import run_sides
    from ..compare.report import save_side_figures, table_rows, write_table
    from ..processing.imaging import range_azimuth

    ck = {label: os.path.join(tmp, ("fit_mmir" if label == "mmIR" else "fit_sionna") + ".h5")
          for label, _ in models}
    sides = run_sides(models, ra_ref, cap.frames[0], iterations=args.iterations, lr=args.lr,
                      seed=args.seed, checkpoints=ck)
    _save_model_renders(models, sides, radar, tmp, args.capture)
    from ..scene.ply_export import save_fitted_ply

    save_fitted_ply(models[0][1], sides["mmIR"].extra["latents"],
                    os.path.join(tmp, "scene_mmir.ply"), overwrite=True)
    _, ranges, az = range_azimuth(cap.frames[0], radar)
    save_side_figures(os.path.join(tmp, "ra_panels.png"), os.path.join(tmp, "loss.png"),
                      ("measured", ra_ref), sides, ranges, az)
    md, _ = write_table(table_rows(os.path.basename(str(args.capture)), sides), tmp, "table2")
    summary = {k: {"metrics_before": v.metrics_before, "metrics_after": v.metrics_after,
                   "seconds_per_iteration": v.seconds_per_it, "loss": v.history.tolist()}
               for k, v in sides.items()}
    with open(os.path.join(tmp, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1, default=float)
    with open(os.path.join(tmp, "report.md"), "w") as f:
        f.write(f"# sionna-mmir {'compare' if len(models) > 1 else 'fit'}\n\ncapture: "
                f"`{args.capture}`\n\nmeshes: {', '.join(names)}\n\n" + open(md).read()
                + "\n![RA](ra_panels.png)\n\n![loss](loss.png)\n")
    if os.path.exists(args.out):
        shutil.rmtree(args.out)
    os.replace(tmp, args.out)
    for k, v in sides.items():
        print(f"{k}: RA correlation {v.metrics_before['ra_correlation']:.3f} -> "
              f"{v.metrics_after['ra_correlation']:.3f}, {v.seconds_per_it:.2f} s/iteration")
    print(f"wrote {args.out}/")
    return 0


def _save_model_renders(models, sides, radar, folder, capture) -> None:
    """``model_<side>.h5``: each fitted model's render as a project HDF5 capture
    (the base model of ``sionna-mmir residual``)."""
    from ..captures.capture import Capture
    from ..paths.render import to_numpy

    for label, model in models:
        adc, _ = model.render(sides[label].extra["latents"], seed=9001)
        stem = "model_mmir" if label == "mmIR" else "model_sionna"
        Capture(frames=to_numpy(adc), radar=radar, source="sionna-mmir fit",
                metadata={"model": label, "capture": str(capture)}).save(
            os.path.join(folder, stem + ".h5"), overwrite=True)


def cmd_fit(args) -> int:
    return _run(args, with_sionna=False)


def cmd_compare(args) -> int:
    return _run(args, with_sionna=True)
