"""``sionna-mmir occupancy``: single-frame 3-D occupancy from a dense virtual array.

Renders meshes (nominal ITU materials, or a fit's per-vertex materials with
``--fitted``) with ``RadarConfig.dense(n_tx, n_rx)`` at the given pose
(single bounce), forms the RAE cube, keeps its 99.9th-percentile voxels as a
point cloud and scores it against points sampled from the clean mesh
(:mod:`sionna_mmir.occupancy`).  Writes ``points.ply``, ``metrics.json`` and
``occupancy.png`` into ``--out``.
"""
from __future__ import annotations


from ..errors import ConfigError
from ..paths.options import SolverOptions
from .args import (FORMATTER, add_materials, add_out, add_pose, add_scaffold, add_solver,
                   mesh_names, named, pose, scaffold_options, solver_options)


def add_parser(sub) -> None:
    p = sub.add_parser("occupancy", help="3-D occupancy point cloud of meshes (or a fitted scene) "
                                         "from a dense virtual array, scored against a clean mesh",
                       formatter_class=FORMATTER)
    p.add_argument("meshes", nargs="+", help="PLY/OBJ scene meshes (object name = file stem)")
    add_out(p, "output folder (points.ply, metrics.json, occupancy.png)", kind="folder")
    p.add_argument("--truth", action="append", metavar="MESH",
                   help="clean reference mesh(es), repeatable (default: the scene meshes)")
    add_materials(p)
    p.add_argument("--fitted", default=None, metavar="PATH",
                   help="fit checkpoint (fit_mmir.h5) or `sionna-mmir fit --out` folder: its "
                        "per-vertex materials / normals / positions replace the nominal ones")
    add_scaffold(p, "none")
    p.add_argument("--normals-smoothing", type=float, default=0.0,
                   help="the fit's Laplacian lambda of the normals")
    p.add_argument("--materials-smoothing", type=float, default=0.0,
                   help="the fit's Laplacian lambda of the materials")
    p.add_argument("--array", default="100x100", metavar="NTXxNRX",
                   help="dense array: n_tx (elevation) x n_rx (azimuth) elements, lambda/2 apart")
    add_pose(p)
    add_solver(p, SolverOptions.dense(sampling="facets", min_rel_power=1e-5),
               fields=("rays", "depth", "sampling", "min_rel_power", "seed"))
    _add_processing_args(p)
    p.set_defaults(run=run)


def _add_processing_args(p) -> None:
    p.add_argument("--n-azimuth", type=int, default=127, help="azimuth FFT bins")
    p.add_argument("--n-elevation", type=int, default=127, help="elevation FFT bins")
    p.add_argument("--percentile", type=float, default=99.9, help="point-cloud threshold")
    p.add_argument("--tau", type=float, default=0.5, help="match threshold [m]")
    p.add_argument("--min-intensity", type=float, default=0.1,
                   help="reference gate on the normalised intensity")
    p.add_argument("--dynamic-range-db", type=float, default=60.0,
                   help="dynamic range of the normalised (log) intensity [dB]")
    p.add_argument("--points-per-m2", type=float, default=400.0,
                   help="reference sampling density on the clean mesh")
    p.add_argument("--no-line-of-sight", action="store_true",
                   help="keep reference points hidden from the radar")
    p.add_argument("--ascii", action="store_true", help="ASCII PLY (default binary)")


def _dense_radar(args):
    from ..processing.rae import check_elevation_aperture
    from ..radar.config import RadarConfig

    try:
        n_tx, n_rx = (int(v) for v in args.array.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--array {args.array}: expected NTXxNRX, e.g. 100x100") from None
    if n_tx < 1 or n_rx < 1:
        raise ConfigError(f"--array {args.array}: element counts must be >= 1")
    position, orientation = pose(args)
    radar = RadarConfig.dense(n_tx, n_rx, position=position, orientation=orientation)
    try:
        check_elevation_aperture(radar)
    except ConfigError as exc:
        raise ConfigError(f"--array {args.array}: {exc}") from None
    return radar


def _check_processing(args, radar) -> None:
    """The processing settings, refused before the (long) render."""
    checks = (("--percentile", 0 <= args.percentile < 100, "in [0, 100)"),
              ("--tau", args.tau > 0, "> 0"), ("--points-per-m2", args.points_per_m2 > 0, "> 0"),
              ("--dynamic-range-db", args.dynamic_range_db > 0, "> 0"),
              ("--n-azimuth", args.n_azimuth >= radar.num_rx,
               f">= the {radar.num_rx} azimuth elements"),
              ("--n-elevation", args.n_elevation >= radar.num_tx,
               f">= the {radar.num_tx} elevation elements"))
    for flag, ok, what in checks:
        if not ok:                                  # NaN fails every comparison
            value = getattr(args, flag[2:].replace("-", "_"))
            raise ConfigError(f"{flag} must be {what}, got {value}")


def run(args) -> int:
    from ..compare.workflow import read_meshes as read_mesh_files
    from ..fit.fitted import load_fitted_scene
    from ..occupancy import occupancy, read_meshes, save_result
    from ..scaffold import prepare_scaffold
    from ..scene import load_scene

    radar = _dense_radar(args)
    _check_processing(args, radar)
    render = solver_options(args).to_dict()
    names = mesh_names(args.meshes)
    truth = mesh_names(args.truth) if args.truth else names
    read_meshes(truth)
    materials = named(args.material, "--material", str)
    scaffold = scaffold_options(args)
    meshes = prepare_scaffold(read_mesh_files(names), scaffold) if scaffold.active else names
    if args.fitted:
        scene = load_fitted_scene(meshes, args.fitted, materials=materials, radar=radar,
                                  normals_smoothing=args.normals_smoothing,
                                  materials_smoothing=args.materials_smoothing)
    else:
        scene = load_scene(meshes, materials=materials, radar=radar)
    res = occupancy(scene, radar, truth, render_options=render, n_azimuth=args.n_azimuth,
                    n_elevation=args.n_elevation, percentile=args.percentile, tau=args.tau,
                    min_intensity=args.min_intensity, dynamic_range_db=args.dynamic_range_db,
                    points_per_m2=args.points_per_m2, seed=args.seed,
                    line_of_sight=not args.no_line_of_sight, progress=True,
                    source=", ".join(args.meshes))
    save_result(res, args.out, overwrite=args.overwrite, binary=not args.ascii,
                title=", ".join(names))
    m = res.metrics
    print(f"{len(res.cloud)} points, {m['n_reference']} reference points: precision "
          f"{m['precision']:.3f}, recall {m['recall']:.3f}, F1 {m['f1']:.3f}, accuracy "
          f"{m['accuracy']:.3f}, RMSE {m['rmse']:.3f} m, R-CD {m['r_cd']:.3f}; frame "
          f"{res.timings['frame_s']:.1f} s")
    print(f"wrote {args.out}/")
    return 0
