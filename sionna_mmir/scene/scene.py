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


def _radio_material(material: str, frequency: float) -> RadioMaterial:
    m = itu_material(material, frequency, allow_out_of_band=True)
    return RadioMaterial(name=f"mmir-{m.name}", relative_permittivity=m.eps_real,
                         conductivity=m.conductivity)


def load_scene(meshes, frequency: float = DEFAULT_FREQUENCY_HZ, materials: dict | None = None,
               radar=None, drop_degenerate: bool = False,
               allow_out_of_band: bool = False) -> RadarScene:
    """Load triangle meshes into a :class:`RadarScene`.

    ===============  =====================================================
    meshes           PLY/OBJ path, ``trimesh.Trimesh``, or ``dict`` name ->
                     path / trimesh (a single mesh is named ``"mesh"``)
    frequency        carrier frequency [Hz], default 77e9
    materials        ``dict`` name -> ITU-R P.2040 material (default
                     ``"concrete"`` for every object)
    radar            optional ``RadarConfig`` (initial pose)
    drop_degenerate  remove triangles < 1e-12 m^2 instead of raising
    allow_out_of_band  use a material outside its ITU-R P.2040 frequency
                     range (extrapolated); by default that raises
                     ``ConfigError`` naming the material and its bands
    returns          :class:`RadarScene`
    ===============  =====================================================

    Raises ``InputValueError`` for bad meshes (see
    :func:`~sionna_mmir.scene.mesh_io.read_mesh`) and ``ConfigError`` for
    unknown materials or a non-positive frequency.
    """
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

    bsdfs: dict[str, RadioMaterial] = {}
    objects: dict[str, MeshObject] = {}
    scene_dict = {"type": "scene"}
    for name, src in meshes.items():
        if not isinstance(name, str) or not name or "." in name:
            raise InputValueError(f"load_scene: object name {name!r} must be a non-empty str without '.'")
        data: TriMeshData = read_mesh(src, drop_degenerate=drop_degenerate,
                                      source=None if isinstance(src, (str, os.PathLike))
                                      else f"object {name!r}")
        mat_name = materials.get(name, "concrete")
        vparams = default_vertex_parameters(mat_name, frequency,
                                            allow_out_of_band=allow_out_of_band)
        key = itu_material(mat_name, frequency, allow_out_of_band=allow_out_of_band).name
        if key not in bsdfs:
            bsdfs[key] = _radio_material(mat_name, frequency)
        scene_dict[name] = to_mitsuba_mesh(data, name, bsdfs[key])
        objects[name] = MeshObject(
            name=name, material=key, faces=data.faces,
            vertex_positions=_tensor(data.vertices),
            vertex_normals=_tensor(data.normals),
            vertex_materials=_tensor(np.tile(vparams, (len(data.vertices), 1))))
    mi_scene = mi.load_dict(scene_dict, optimize=False)
    return RadarScene(mi_scene, objects, frequency=frequency, radar=radar)
