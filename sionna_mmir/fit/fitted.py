"""Reload a fitted scene: meshes + the latents of a fit checkpoint.

``sionna-mmir fit --out DIR`` writes ``DIR/fit_mmir.h5``
(:func:`~sionna_mmir.fit.fitter.save_checkpoint`): the final latents keyed
``"<object>.materials"`` (``[Nv, 6]``, :mod:`~sionna_mmir.fit.reparam`
latents), ``"<object>.normals"`` (``[Nv, 3]``), ``"<object>.positions"``
(``[Nv, 3]`` [m]), ``"beam.{tx,rx}.*"`` and ``"pose.*"``.  The meshes
themselves are not stored: pass the meshes the fit was given, prepared the
same way (``--denoise`` / ``--planes`` / ``--shading``), so that every object
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
    """Physical per-vertex fields of a fit: ``{(object, field): float64 [Nv, k]}``.

    ``latents``: the checkpoint's ``dict``; ``scene``: the
    :class:`~sionna_mmir.scene.RadarScene` they belong to.  Smoothing
    ``lambda``s must be the fit's (``--normals-smoothing`` /
    ``--materials-smoothing``; 0 = raw per-vertex latents).  Unknown objects
    and vertex-count mismatches raise
    :class:`~sionna_mmir.errors.InputValueError` naming ``source``.
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
    """A :class:`~sionna_mmir.scene.RadarScene` with a fit's materials / normals / positions.

    ============================  ==============================================
    ``meshes``                    as :func:`~sionna_mmir.scene.load_scene` (the
                                  fit's meshes, prepared as for the fit)
    ``checkpoint``                ``fit_mmir.h5``, or the ``fit --out`` folder
    ``materials``                 nominal ITU materials per object (the
                                  ``--material`` of the fit; sets the objects'
                                  radio material, the per-vertex parameters are
                                  the fit's)
    ``radar``                     initial radar / pose of the scene
    ``normals_smoothing``,        the fit's Laplacian ``lambda``s
    ``materials_smoothing``
    ============================  ==============================================
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


def prepared_meshes(paths: dict, *, denoise: bool = False, planes: bool = False,
                    shading: str = "shared") -> dict:
    """The fit command's meshes: ``paths`` (name -> PLY/OBJ) as is, or read and put
    through :func:`~sionna_mmir.scene.prepare_scaffold` (``--denoise`` /
    ``--planes`` / ``--shading`` other than ``shared``); returns a ``dict`` for
    :func:`~sionna_mmir.scene.load_scene`."""
    if not (denoise or planes or shading != "shared"):
        return dict(paths)
    import trimesh

    from ..scene import prepare_scaffold, read_mesh

    meshes = {}
    for name, path in paths.items():
        data = read_mesh(path)
        meshes[name] = trimesh.Trimesh(data.vertices, data.faces, process=False)
    return prepare_scaffold(meshes, denoise=denoise, planes=planes, shading=shading)
