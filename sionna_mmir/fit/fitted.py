"""Reload a fitted scene: meshes + the latents of a fit checkpoint.

``sionna-mmir fit --out DIR`` writes ``DIR/fit_mmir.h5``
(:func:`~sionna_mmir.fit.fitter.save_checkpoint`): the final latents keyed
``"<object>.materials"`` (``[Nv, 6]``, :mod:`~sionna_mmir.fit.reparam`
latents), ``"<object>.normals"`` (``[Nv, 3]``), ``"<object>.positions"``
(``[Nv, 3]`` [m]), ``"beam.{tx,rx}.*"`` and ``"pose.*"``.  The meshes
themselves are not stored: pass the meshes the fit was given, prepared the
same way (``--scaffold`` / ``--shading``), so that every object
has the checkpoint's vertex count.

Materials, normals and positions are written into the scene.  Beam-pattern
latents belong to the fitted radar's elements (e.g. the cascade's 12 Tx and
16 Rx) and the fitted pose to that radar, so both are left out: a fitted
scene is re-rendered with any radar at any pose.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import InputValueError
from . import reparam

_FIELDS = ("materials", "normals", "positions")


def fitted_fields(latents: dict, scene, normals_smoothing: float = 0.0,
                  materials_smoothing: float = 0.0, source: str = "checkpoint") -> dict:
    """Physical per-vertex fields of a fit.

    Parameters
    ----------
    latents : dict
        The checkpoint's latents (name -> ndarray).
    scene : RadarScene
        The scene they belong to.
    normals_smoothing, materials_smoothing : float, optional
        The fit's Laplacian parameters ``lambda`` (``--normals-smoothing`` /
        ``--materials-smoothing``; 0 = raw per-vertex latents).
    source : str, optional
        Name of the checkpoint in error messages.

    Returns
    -------
    dict
        ``(object, field) -> ndarray of float64, shape (n_vertices, k)``:
        ``materials`` (k = 6, physical), ``normals`` (3), ``positions`` (3, m).

    Raises
    ------
    InputValueError
        An object missing from the scene, or a vertex-count mismatch.
    """
    from .smooth_param import LaplacianParam

    out = {}
    for key, z in latents.items():
        name, _, field = key.rpartition(".")
        if field not in _FIELDS or name.startswith(("beam", "pose")):
            continue
        obj = scene.mesh_objects.get(name)
        if obj is None:
            raise InputValueError(f"{source}: the fit has object {name!r}, the meshes have "
                                  f"{sorted(scene.mesh_objects)}")
        nv = obj.vertex_positions.shape[0]
        z = np.asarray(z, dtype=np.float64)
        if z.shape[0] != nv:
            raise InputValueError(
                f"{source}: object {name!r} has {z.shape[0]} vertices in the fit and {nv} in "
                "the mesh (prepare the meshes as for the fit: --denoise / --planes / --shading)")
        lam = {"normals": normals_smoothing, "materials": materials_smoothing}.get(field, 0.0)
        if lam > 0:
            z = LaplacianParam(obj.faces, nv, float(lam)).from_latent(z)
        out[(name, field)] = reparam.to_physical(z) if field == "materials" else z
    return out


def load_fitted_scene(meshes, checkpoint, *, materials: dict | None = None, radar=None,
                      normals_smoothing: float = 0.0, materials_smoothing: float = 0.0):
    """A scene carrying a fit's materials, normals and positions.

    Parameters
    ----------
    meshes : str, trimesh.Trimesh or dict
        As :func:`~sionna_mmir.scene.load_scene`: the fit's meshes, prepared as
        for the fit (:func:`sionna_mmir.scaffold.prepare_scaffold`).
    checkpoint : str or os.PathLike
        ``fit_mmir.h5``, or the ``sionna-mmir fit --out`` folder holding it.
    materials : dict, optional
        Nominal ITU material per object (the fit's ``--material``; it sets the
        objects' radio material, the per-vertex parameters are the fit's).
    radar : RadarConfig, optional
        Initial radar and pose of the scene.
    normals_smoothing, materials_smoothing : float, optional
        The fit's Laplacian parameters ``lambda``.

    Returns
    -------
    RadarScene

    Raises
    ------
    InputValueError
        Missing or unreadable checkpoint, object or vertex-count mismatch.
    """
    import mitsuba as mi

    from ..scene import load_scene
    from .fitter import load_checkpoint

    path = os.fspath(checkpoint)
    if os.path.isdir(path):
        path = os.path.join(path, "fit_mmir.h5")
    if not os.path.isfile(path):
        raise InputValueError(f"{path}: fit checkpoint does not exist")
    latents = load_checkpoint(path)["latents"]
    scene = load_scene(meshes, materials=materials, radar=radar)
    fields = fitted_fields(latents, scene, normals_smoothing, materials_smoothing, path)
    for (name, field), value in fields.items():
        obj = scene.mesh_objects[name]
        a = np.ascontiguousarray(value, dtype=np.float32)
        setattr(obj, f"vertex_{field}", mi.TensorXf(mi.Float(a.ravel()), a.shape))
    scene.sync()
    return scene
