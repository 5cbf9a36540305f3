"""``load_scene``: meshes, a Sionna scene or a material PLY -> :class:`RadarScene`.

The dispatcher of the scene importers: triangle meshes (PLY / OBJ / trimesh,
with ITU-R P.2040 materials by name), Sionna RT scenes and Mitsuba XML
(:mod:`.sionna_import`), and PLYs with per-vertex materials
(:mod:`.ply_export`).  Meshes are expected in the radar's scene frame
(metres; the radar pose places the radar in it: ``+x`` boresight, ``+y``
left, ``+z`` up for an unrotated radar).
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radio_materials import default_vertex_parameters, itu_material
from . import ply_export, sionna_import
from .mesh_io import TriMeshData, read_mesh
from .scene import DEFAULT_FREQUENCY_HZ, ObjectData, RadarScene, scene_from_objects


def load_scene(meshes, frequency: float = DEFAULT_FREQUENCY_HZ, materials: dict | None = None,
               radar=None, drop_degenerate: bool = False,
               allow_out_of_band: bool | None = None, **options) -> RadarScene:
    """Load triangle meshes, a Sionna scene or a material PLY into a :class:`RadarScene`.

    Parameters
    ----------
    meshes : str or os.PathLike or trimesh.Trimesh or dict or sionna.rt.Scene
        PLY/OBJ path, ``trimesh.Trimesh``, or ``dict`` name ->
        path / trimesh (a single mesh is named ``"mesh"``);
        a ``sionna.rt.Scene``, a Sionna / Mitsuba XML path
        (e.g. ``sionna.rt.scene.simple_street_canyon``), see
        :func:`~sionna_mmir.scene.sionna_import.load_sionna_scene`;
        or a PLY written by
        :func:`~sionna_mmir.scene.ply_export.save_scene_ply`
        (per-vertex materials restored exactly)
    frequency : float, optional
        carrier frequency [Hz], default 77e9
    materials : dict, optional
        name -> ITU-R P.2040 material (default
        ``"concrete"`` for every object; Sionna scenes: see
        ``load_sionna_scene``)
    radar : RadarConfig, optional
        the radar (its pose is the scene's initial radar pose)
    drop_degenerate : bool, optional
        remove triangles < 1e-12 m^2 instead of raising
    allow_out_of_band : bool, optional
        use a material outside its ITU-R P.2040 frequency
        range (extrapolated).  ``None`` (default): meshes
        raise ``ConfigError`` naming the material and its
        bands; Sionna scenes extrapolate with an
        ``OutOfBandMaterialWarning`` (their built-in scenes
        use brick and marble, tabulated to 40 / 60 GHz)
    **options
        Sionna sources only: ``shading``, ``merge_shapes``

    Returns
    -------
    RadarScene

    Raises
    ------
    InputValueError
        Bad meshes (see :func:`~sionna_mmir.scene.mesh_io.read_mesh`).
    ConfigError
        Unknown materials or a non-positive frequency.
    """
    if sionna_import.is_sionna_source(meshes):
        return sionna_import.load_sionna_scene(
            meshes, frequency=frequency, materials=materials, radar=radar,
            drop_degenerate=drop_degenerate, allow_out_of_band=allow_out_of_band, **options)
    if options:
        raise ConfigError(f"load_scene: options {sorted(options)} apply to Sionna scenes only")
    if ply_export.is_scene_ply(meshes):
        return ply_export.load_scene_ply(meshes, frequency=frequency, materials=materials,
                                         radar=radar)
    if not isinstance(meshes, dict):
        meshes = {"mesh": meshes}
    if not meshes:
        raise InputValueError("load_scene: no meshes given")
    materials = dict(materials or {})
    unknown = sorted(set(materials) - set(meshes))
    if unknown:
        raise ConfigError(f"load_scene: materials given for unknown objects {unknown}")
    if not np.isfinite(float(frequency)) or float(frequency) <= 0:
        raise ConfigError(f"frequency must be a positive finite number [Hz], got {frequency!r}")
    objects = {}
    for name, src in meshes.items():
        if not isinstance(name, str) or not name or "." in name:
            raise InputValueError(f"load_scene: object name {name!r} must be a non-empty str without '.'")
        data: TriMeshData = read_mesh(src, drop_degenerate=drop_degenerate,
                                      source=None if isinstance(src, (str, os.PathLike))
                                      else f"object {name!r}")
        mat_name = materials.get(name, "concrete")
        vparams = default_vertex_parameters(mat_name, frequency,
                                            allow_out_of_band=bool(allow_out_of_band))
        key = itu_material(mat_name, frequency, allow_out_of_band=bool(allow_out_of_band)).name
        objects[name] = ObjectData(data, key, np.tile(vparams, (len(data.vertices), 1)))
    return scene_from_objects(objects, frequency=frequency, radar=radar)
