"""The fit workflow behind ``sionna-mmir fit`` and ``sionna-mmir compare``.

:class:`FitRequest` says what to fit (capture, meshes, radar pose, solver and
scaffold settings, budget); :func:`run_fit` loads the capture and the
meshes, fits mmIR (and, for a comparison, the Sionna RT baseline with the
same loss, Adam settings and budget) and writes the report folder
atomically: ``summary.json``, ``report.md``, ``table2.{md,csv}``, RA panels,
the fitted scene ``scene_mmir.ply`` (per-vertex materials),
loss curves, the fit checkpoints ``fit_*.h5`` (a killed fit resumes from
``<out>.partial``) and the fitted models' renders ``model_*.h5``.
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil

import numpy as np

from ..errors import ConfigError, InputValueError
from ..paths.options import SolverOptions
from ..scaffold.prepare import ScaffoldOptions


@dataclasses.dataclass
class FitRequest:
    """What one fit (or comparison) does.

    Parameters
    ----------
    capture : str
        Capture path (any format :func:`~sionna_mmir.captures.load_capture` reads).
    meshes : dict
        Object name -> mesh path, placed in the radar's scene frame.
    out : str
        Report folder.
    materials : dict
        Object name -> initial ITU-R P.2040 material (default concrete).
    position, orientation : tuple
        Radar pose: position [m], (yaw, pitch, roll) [rad].
    solver : SolverOptions
        mmIR solver settings (default :meth:`SolverOptions.fit`).
    scaffold : ScaffoldOptions
        Mesh repair before fitting (default none).
    with_sionna : bool
        Fit the Sionna RT baseline too.
    """

    capture: str
    meshes: dict
    out: str
    materials: dict = dataclasses.field(default_factory=dict)
    frame: int | None = None
    calib_dir: str | None = None
    position: tuple = (0.0, 0.0, 0.0)
    orientation: tuple = (0.0, 0.0, 0.0)
    iterations: int = 30
    lr: float = 0.05
    seed: int = 0
    solver: SolverOptions = dataclasses.field(default_factory=SolverOptions.fit)
    scaffold: ScaffoldOptions = dataclasses.field(default_factory=ScaffoldOptions.none)
    normals_smoothing: float = 0.0
    materials_smoothing: float = 0.0
    with_sionna: bool = False
    sionna_samples: int = 20_000
    resume: bool = False
    overwrite: bool = False


def read_meshes(paths: dict) -> dict:
    """Name -> ``trimesh.Trimesh`` of validated mesh files."""
    import trimesh

    from ..scene import read_mesh

    meshes = {}
    for name, path in paths.items():
        data = read_mesh(path)
        meshes[name] = trimesh.Trimesh(data.vertices, data.faces, process=False)
    return meshes


def load_inputs(req: FitRequest):
    """``(capture, radar, meshes, scene)`` of a request (meshes repaired by its scaffold)."""
    from ..captures.loader import load_capture
    from ..scaffold import prepare_scaffold
    from ..scene import load_scene

    if os.path.exists(req.out) and not os.path.isdir(req.out):
        raise ConfigError(f"{req.out}: exists and is not a folder (the output is a report "
                          "folder); remove it or choose another name")
    if os.path.exists(req.out) and not (req.overwrite or req.resume):
        raise FileExistsError(f"{req.out}: report folder exists (use --overwrite or --resume)")
    if req.iterations < 1:
        raise ConfigError(f"--iterations must be >= 1, got {req.iterations}")
    cap = load_capture(req.capture, frame=req.frame, calib_dir=req.calib_dir)
    if not np.isfinite(cap.frames.real).all() or not np.isfinite(cap.frames.imag).all():
        raise InputValueError(f"{req.capture}: capture holds NaN or Inf samples")
    radar = dataclasses.replace(cap.radar, position=tuple(req.position),
                                orientation=tuple(req.orientation))
    meshes = dict(req.meshes)
    if req.scaffold.active:
        meshes = prepare_scaffold(read_meshes(meshes), req.scaffold)
    scene = load_scene(meshes, materials=req.materials, radar=radar)
    return cap, radar, meshes, scene


def check_overlap(model, where) -> None:
    """Raise :class:`InputValueError` if no ray from the radar hits the meshes."""
    from ..paths.render import to_numpy

    adc, _ = model.render(model.latents(), seed=12345)
    if not np.any(to_numpy(adc)):
        raise InputValueError(f"{where}: the meshes and the capture do not overlap: no ray "
                              "from the radar hits the meshes (check the radar pose and the "
                              "mesh coordinates: meshes are expected in the radar's scene "
                              "frame, +x boresight, +y left, +z up)")


def build_models(req: FitRequest, scene, radar, meshes) -> list:
    """``[(label, model)]``: mmIR, and the Sionna RT baseline for a comparison."""
    from ..fit import MMIRModel, SionnaModel

    mm = MMIRModel(scene, solver_options=req.solver, normals_smoothing=req.normals_smoothing,
                   materials_smoothing=req.materials_smoothing)
    check_overlap(mm, req.capture)
    models = [("mmIR", mm)]
    if req.with_sionna:
        from ..baseline import SionnaBaseline

        models.append(("Sionna RT", SionnaModel(SionnaBaseline(
            meshes, {k: req.materials.get(k, "concrete") for k in meshes}, radar,
            samples_per_src=req.sionna_samples))))
    return models


def run_fit(req: FitRequest) -> dict:
    """Fit, write the report folder ``req.out`` and return the summary."""
    from .harness import target_ra

    cap, radar, meshes, scene = load_inputs(req)
    ra_ref = target_ra(cap.frames, radar)
    models = build_models(req, scene, radar, meshes)
    # work in <out>.partial; a killed fit leaves its checkpoints there for resume
    tmp = req.out + ".partial"
    if os.path.exists(tmp) and not req.resume:
        shutil.rmtree(tmp)
    os.makedirs(tmp, exist_ok=True)
    if req.resume and os.path.isdir(req.out):
        for f in os.listdir(req.out):
            if f.endswith(".h5") and not os.path.exists(os.path.join(tmp, f)):
                shutil.copy(os.path.join(req.out, f), os.path.join(tmp, f))
    try:
        return _fit_and_report(req, cap, radar, meshes, models, ra_ref, tmp)
    except Exception:
        if not req.resume:
            shutil.rmtree(tmp, ignore_errors=True)
        raise


def _fit_and_report(req, cap, radar, meshes, models, ra_ref, tmp) -> dict:
    from ..fit.export import save_fitted_ply
    from ..processing.imaging import range_azimuth
    from .harness import run_sides
    from .report import save_side_figures, table_rows, write_table

    ck = {label: os.path.join(tmp, ("fit_mmir" if label == "mmIR" else "fit_sionna") + ".h5")
          for label, _ in models}
    sides = run_sides(models, ra_ref, cap.frames[0], iterations=req.iterations, lr=req.lr,
                      seed=req.seed, checkpoints=ck)
    save_model_renders(models, sides, radar, tmp, req.capture)
    save_fitted_ply(models[0][1], sides["mmIR"].extra["latents"],
                    os.path.join(tmp, "scene_mmir.ply"), overwrite=True)
    _, ranges, az = range_azimuth(cap.frames[0], radar)
    save_side_figures(os.path.join(tmp, "ra_panels.png"), os.path.join(tmp, "loss.png"),
                      ("measured", ra_ref), sides, ranges, az)
    md, _ = write_table(table_rows(os.path.basename(str(req.capture)), sides), tmp, "table2")
    summary = {k: {"metrics_before": v.metrics_before, "metrics_after": v.metrics_after,
                   "seconds_per_iteration": v.seconds_per_it, "loss": v.history.tolist()}
               for k, v in sides.items()}
    with open(os.path.join(tmp, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1, default=float)
    with open(os.path.join(tmp, "report.md"), "w") as f:
        f.write(f"# sionna-mmir {'compare' if len(models) > 1 else 'fit'}\n\ncapture: "
                f"`{req.capture}`\n\nmeshes: {', '.join(meshes)}\n\n" + open(md).read()
                + "\n![RA](ra_panels.png)\n\n![loss](loss.png)\n")
    if os.path.exists(req.out):
        shutil.rmtree(req.out)
    os.replace(tmp, req.out)
    return summary


def save_model_renders(models, sides, radar, folder, capture) -> None:
    """``model_<side>.h5``: each fitted model's render as a project HDF5
    capture (the base model of ``sionna-mmir residual``)."""
    from ..captures.capture import Capture
    from ..paths.render import to_numpy

    for label, model in models:
        adc, _ = model.render(sides[label].extra["latents"], seed=9001)
        stem = "model_mmir" if label == "mmIR" else "model_sionna"
        Capture(frames=to_numpy(adc), radar=radar, source="sionna-mmir fit",
                metadata={"model": label, "capture": str(capture)}).save(
            os.path.join(folder, stem + ".h5"), overwrite=True)
