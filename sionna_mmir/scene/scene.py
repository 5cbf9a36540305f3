"""``RadarScene``: a Sionna RT scene owning differentiable per-vertex tensors.

Sionna 2.2's ``sionna.rt.load_scene`` hard-codes ``Scene(mi_scene=...)``; this
module builds the Mitsuba scene itself (one ``mi.Mesh`` per object, each with a
Sionna ``RadioMaterial`` as BSDF) and constructs :class:`RadarScene` the same
way.  Per object it owns Dr.Jit tensors

==================  =======  ================================================
vertex_positions    [Nv, 3]  positions [m]
vertex_normals      [Nv, 3]  shading normals (unit), from trimesh
vertex_materials    [Nv, 6]  ``[eps_real, eps_imag, sigma_h [m], l_c [m],
                             tau, d [m]]`` (see
                             :func:`~sionna_mmir.radio_materials.default_vertex_parameters`)
==================  =======  ================================================

plus the radar pose ``position`` [3] (m) and ``orientation`` [3] (yaw, pitch,
roll; rad).  :meth:`RadarScene.sync` pushes them into Mitsuba, where
``shape.eval_attribute_3("vertex_mmir_normal" | "vertex_mmir_mat0" |
"vertex_mmir_mat1", si)`` interpolates them barycentrically at a hit.

Frequency: every object's Sionna BSDF is a plain ``RadioMaterial`` whose
permittivity / conductivity are evaluated once, at load, from the package's
ITU-R P.2040 table (``allow_out_of_band=True``), with *no* frequency-update
callback.  Setting ``scene.frequency`` therefore never raises for ITU
materials whose Sionna band excludes 77 GHz (Sionna's ``ITURadioMaterial``
would), and never overwrites the learnable ``vertex_materials``.
"""
from __future__ import annotations

import os

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radio_materials import default_vertex_parameters, itu_material
from ..utils.backend import init_backend
from .mesh_io import TriMeshData, read_mesh, to_mitsuba_mesh

init_backend()

import mitsuba as mi  # noqa: E402  (after init_backend, on purpose)
from sionna.rt import RadioMaterial, Scene  # noqa: E402

#: Default carrier frequency [Hz].
DEFAULT_FREQUENCY_HZ = 77e9
#: Vertex attribute names read by the BSDF via ``shape.eval_attribute_3``.
ATTR_NORMAL = "vertex_mmir_normal"
ATTR_MAT0 = "vertex_mmir_mat0"  # eps_real, eps_imag, sigma_h
ATTR_MAT1 = "vertex_mmir_mat1"  # l_c, tau, d


def _tensor(a: np.ndarray) -> mi.TensorXf:
    a = np.ascontiguousarray(a, dtype=np.float32)
    return mi.TensorXf(mi.Float(a.ravel()), a.shape)


@dataclass
class MeshObject:
    """Differentiable state of one scene object (see module docstring)."""

    name: str
    material: str
    faces: np.ndarray
    vertex_positions: mi.TensorXf
    vertex_normals: mi.TensorXf
    vertex_materials: mi.TensorXf


class RadarScene(Scene):
    """A ``sionna.rt.Scene`` with per-vertex differentiable radar parameters.

    ==========  ==========================================================
    mi_scene    Mitsuba scene holding one ``mi.Mesh`` per object
    objects     ``dict`` name -> :class:`MeshObject` (kept as ``mesh_objects``;
                Sionna's ``objects`` holds the ``SceneObject``s)
    frequency   carrier frequency [Hz] (default 77 GHz)
    radar       optional :class:`~sionna_mmir.radar.config.RadarConfig`
                (its ``position`` [m] / ``orientation`` [rad] start the pose)
    ==========  ==========================================================

    Use :func:`load_scene` rather than this constructor.
    """

    def __init__(self, mi_scene: mi.Scene, objects: dict, frequency: float = DEFAULT_FREQUENCY_HZ,
                 radar=None):
        super().__init__(mi_scene=mi_scene)
        self.frequency = frequency
        self.mesh_objects: dict[str, MeshObject] = objects
        self.radar = radar
        pos = np.zeros(3) if radar is None else np.asarray(radar.position, dtype=float)
        ori = np.zeros(3) if radar is None else np.asarray(radar.orientation, dtype=float)
        self.position = _tensor(pos.reshape(3))
        self.orientation = _tensor(ori.reshape(3))
        self.sync()

    @property
    def frequency(self):
        """``mi.Float``: carrier frequency [Hz]; raises ``ConfigError`` if <= 0."""
        return Scene.frequency.fget(self)

    @frequency.setter
    def frequency(self, f):
        if not np.isfinite(float(f)) or float(f) <= 0:
            raise ConfigError(f"frequency must be a positive finite number [Hz], got {f!r}")
        try:
            Scene.frequency.fset(self, f)
        except ValueError as exc:  # a user-added ITURadioMaterial out of band
            raise ConfigError(f"frequency {float(f):g} Hz rejected by a radio material: {exc}") from exc

    def mesh(self, name: str) -> mi.Mesh:
        """The Mitsuba mesh of object ``name``."""
        return self.get(name).mi_mesh

    def sync(self) -> None:
        """Push positions into Mitsuba and (re)attach normal / material attributes.

        Positions go through ``mi.traverse(scene)`` so the acceleration
        structure is rebuilt; the update is differentiable when the tensors
        have gradients enabled (AD variant).
        """
        scene_params = mi.traverse(self.mi_scene)
        for name, obj in self.mesh_objects.items():
            key = f"{name}.vertex_positions"
            scene_params[key] = obj.vertex_positions.array
            mesh = self.mesh(name)
            mat = obj.vertex_materials
            values = {ATTR_NORMAL: obj.vertex_normals.array,
                      ATTR_MAT0: mat[:, 0:3].array, ATTR_MAT1: mat[:, 3:6].array}
            for attr, value in values.items():
                if mesh.has_attribute(attr):
                    scene_params[f"{name}.{attr}"] = value
                else:
                    mesh.add_attribute(attr, 3, value)
        scene_params.update()

    def params(self) -> dict:
        """Differentiable tensors for an optimiser.

        Keys ``"<object>.vertex_positions" | ".vertex_normals" |
        ".vertex_materials"`` and ``"radar.position" | "radar.orientation"``.
        Call :meth:`sync` after changing any of them.
        """
        out = {}
        for name, obj in self.mesh_objects.items():
            for key in ("vertex_positions", "vertex_normals", "vertex_materials"):
                out[f"{name}.{key}"] = getattr(obj, key)
        out["radar.position"] = self.position
        out["radar.orientation"] = self.orientation
        return out


def _radio_material(label: str, vertex_materials: np.ndarray, frequency: float) -> RadioMaterial:
    """Sionna BSDF of one object: the mean per-vertex ``eps_real`` and the
    conductivity of the mean ``eps_imag`` at ``frequency``."""
    from ..radio_materials.itu_table import EPSILON_0

    eps_real, eps_imag = np.mean(vertex_materials[:, :2], axis=0)
    sigma = float(eps_imag) * 2.0 * np.pi * float(frequency) * EPSILON_0
    return RadioMaterial(name=f"mmir-{label}", relative_permittivity=max(float(eps_real), 1.0),
                         conductivity=max(sigma, 0.0))


@dataclass
class ObjectData:
    """One object to build: validated mesh, material label, per-vertex materials.

    ================  ====================================================
    mesh              :class:`~sionna_mmir.scene.mesh_io.TriMeshData`
    material          label (an ITU-R P.2040 class or a free name)
    vertex_materials  ``np.ndarray`` [Nv, 6] (order
                      :data:`~sionna_mmir.radio_materials.VERTEX_PARAMETER_NAMES`)
    ================  ====================================================
    """

    mesh: TriMeshData
    material: str
    vertex_materials: np.ndarray


def scene_from_objects(objects: dict, frequency: float = DEFAULT_FREQUENCY_HZ,
                       radar=None) -> RadarScene:
    """Build a :class:`RadarScene` from ``dict`` name -> :class:`ObjectData`.

    The importers (meshes, Sionna scenes, material PLYs) all end here.
    Raises ``InputValueError`` for a bad object name or a material array of
    the wrong shape / with NaN.
    """
    if not objects:
        raise InputValueError("load_scene: no meshes given")
    if not np.isfinite(float(frequency)) or float(frequency) <= 0:
        raise ConfigError(f"frequency must be a positive finite number [Hz], got {frequency!r}")
    bsdfs: dict[str, RadioMaterial] = {}
    built: dict[str, MeshObject] = {}
    scene_dict = {"type": "scene"}
    for name, obj in objects.items():
        if not isinstance(name, str) or not name or "." in name:
            raise InputValueError(f"load_scene: object name {name!r} must be a non-empty str without '.'")
        mats = np.asarray(obj.vertex_materials, dtype=np.float64)
        if mats.shape != (len(obj.mesh.vertices), 6) or not np.isfinite(mats).all():
            raise InputValueError(f"load_scene: object {name!r}: vertex materials must be finite "
                                  f"[{len(obj.mesh.vertices)}, 6], got {mats.shape}")
        if obj.material not in bsdfs:
            bsdfs[obj.material] = _radio_material(obj.material, mats, frequency)
        scene_dict[name] = to_mitsuba_mesh(obj.mesh, name, bsdfs[obj.material])
        built[name] = MeshObject(
            name=name, material=obj.material, faces=obj.mesh.faces,
            vertex_positions=_tensor(obj.mesh.vertices),
            vertex_normals=_tensor(obj.mesh.normals), vertex_materials=_tensor(mats))
    mi_scene = mi.load_dict(scene_dict, optimize=False)
    return RadarScene(mi_scene, built, frequency=frequency, radar=radar)


def load_scene(meshes, frequency: float = DEFAULT_FREQUENCY_HZ, materials: dict | None = None,
               radar=None, drop_degenerate: bool = False,
               allow_out_of_band: bool | None = None, **options) -> RadarScene:
    """Load triangle meshes, a Sionna scene or a material PLY into a :class:`RadarScene`.

    =================  ===================================================
    meshes             PLY/OBJ path, ``trimesh.Trimesh``, or ``dict`` name ->
                       path / trimesh (a single mesh is named ``"mesh"``);
                       a ``sionna.rt.Scene``, a Sionna / Mitsuba XML path
                       (e.g. ``sionna.rt.scene.simple_street_canyon``), see
                       :func:`~sionna_mmir.scene.sionna_import.load_sionna_scene`;
                       or a PLY written by
                       :func:`~sionna_mmir.scene.ply_export.save_scene_ply`
                       (per-vertex materials restored exactly)
    frequency          carrier frequency [Hz], default 77e9
    materials          ``dict`` name -> ITU-R P.2040 material (default
                       ``"concrete"`` for every object; Sionna scenes: see
                       ``load_sionna_scene``)
    radar              optional ``RadarConfig`` (initial pose)
    drop_degenerate    remove triangles < 1e-12 m^2 instead of raising
    allow_out_of_band  use a material outside its ITU-R P.2040 frequency
                       range (extrapolated).  ``None`` (default): meshes
                       raise ``ConfigError`` naming the material and its
                       bands; Sionna scenes extrapolate with an
                       ``OutOfBandMaterialWarning`` (their built-in scenes
                       use brick and marble, tabulated to 40 / 60 GHz)
    options            Sionna sources only: ``shading``, ``merge_shapes``
    returns            :class:`RadarScene`
    =================  ===================================================

    Raises ``InputValueError`` for bad meshes (see
    :func:`~sionna_mmir.scene.mesh_io.read_mesh`) and ``ConfigError`` for
    unknown materials or a non-positive frequency.
    """
    from . import ply_export, sionna_import

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
