"""Fitted scenes out: a fit's latents written into its scene, and to PLY.

:func:`fitted_scene` turns the latents of a fitted
:class:`~sionna_mmir.fit.MMIRModel` (a :class:`~sionna_mmir.fit.FitResult`, a
dict, or a checkpoint file) into the physical per-vertex values of its
:class:`~sionna_mmir.scene.RadarScene`; :func:`save_fitted_ply` writes that
scene as a PLY with per-vertex materials
(:func:`sionna_mmir.scene.ply_export.save_scene_ply`), viewable in MeshLab or
Blender and loadable with :func:`sionna_mmir.load_scene`.
"""
from __future__ import annotations

import os

from ..errors import ConfigError
from ..scene.ply_export import save_scene_ply
from ..scene.scene import _tensor
from .fitter import load_checkpoint


def fitted_scene(model, fit):
    """Write fitted physical values into ``model.scene`` and return the scene.

    Parameters
    ----------
    model : MMIRModel
        The model that was fitted (its smoothing parameterisations map
        latents to values).
    fit : FitResult, dict or path
        A fit result, a dict of latents, or the path of a fit checkpoint
        (``fit_mmir.h5``).

    Returns
    -------
    RadarScene
        ``model.scene`` with per-vertex materials, unit normals and (if
        learned) positions / pose.
    """
    if isinstance(fit, (str, os.PathLike)):
        latents = load_checkpoint(fit)["latents"]
    else:
        latents = getattr(fit, "latents", fit)
    scene = model.scene
    missing = sorted(set(latents) - set(model.latents()))
    if missing:
        raise ConfigError(f"fitted_scene: latents {missing[:5]} do not belong to this model")
    values = model.physical(latents)
    for name, obj in scene.mesh_objects.items():
        for key, attr in (("materials", "vertex_materials"), ("normals", "vertex_normals"),
                          ("positions", "vertex_positions")):
            if f"{name}.{key}" in values:
                setattr(obj, attr, _tensor(values[f"{name}.{key}"]))
    if "pose.position" in values:
        scene.position = _tensor(values["pose.position"].reshape(3))
        scene.orientation = _tensor(values["pose.orientation"].reshape(3))
    scene.sync()
    return scene


def save_fitted_ply(model, fit, path, overwrite: bool = False) -> str:
    """:func:`fitted_scene` then :func:`save_scene_ply`; returns the path."""
    return save_scene_ply(fitted_scene(model, fit), path, overwrite=overwrite)
