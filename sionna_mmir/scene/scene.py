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
roll; rad).

One home per fact:

* the per-vertex materials are the tensor of the object's Sionna radio
  material (:class:`~sionna_mmir.scene.vertex_material.VertexRadioMaterial`,
  ``scene.get(name).radio_material``); ``MeshObject.vertex_materials`` reads
  and writes that tensor, and Sionna RT's own solvers evaluate it per hit;
* the radar pose is the scene's: ``position`` / ``orientation`` are its
  differentiable state, started from ``scene.radar`` and reset when a radar
  is assigned (``scene.radar = radar``); a solver call with a radar at
  another pose is refused.

:meth:`RadarScene.sync` pushes vertex positions into Mitsuba (ray tracing
uses them).  Setting ``scene.frequency`` never overwrites the learnable
materials (the radio materials have no frequency-update callback).
"""
from __future__ import annotations


from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, InputValueError
from ..utils.backend import init_backend
from .mesh_io import TriMeshData, to_mitsuba_mesh
from .vertex_material import VertexRadioMaterial

init_backend()

import mitsuba as mi  # noqa: E402  (after init_backend, on purpose)
from sionna.rt import Scene  # noqa: E402

#: Default carrier frequency [Hz].
DEFAULT_FREQUENCY_HZ = 77e9


def _tensor(a: np.ndarray) -> mi.TensorXf:
    a = np.ascontiguousarray(a, dtype=np.float32)
    return mi.TensorXf(mi.Float(a.ravel()), a.shape)


class MeshObject:
    """Differentiable state of one scene object (see the module docstring).

    Parameters
    ----------
    name : str
        Object name.
    radio_material : VertexRadioMaterial
        The object's Sionna radio material (holds ``vertex_materials``).
    faces : numpy.ndarray
        ``[F, 3]`` vertex indices.
    vertex_positions, vertex_normals : mi.TensorXf
        ``[Nv, 3]`` positions [m] and unit shading normals.
    """

    def __init__(self, name: str, radio_material: VertexRadioMaterial, faces: np.ndarray,
                 vertex_positions, vertex_normals):
        self.name = name
        self.radio_material = radio_material
        self.faces = faces
        self.vertex_positions = vertex_positions
        self.vertex_normals = vertex_normals
        radio_material.bind(self)

    @property
    def material(self) -> str:
        """The material class the parameters started from (e.g. ``"concrete"``)."""
        return self.radio_material.label

    @property
    def vertex_materials(self):
        """``mi.TensorXf [Nv, 6]``: the radio material's per-vertex parameters."""
        return self.radio_material.vertex_parameters

    @vertex_materials.setter
    def vertex_materials(self, value):
        self.radio_material.vertex_parameters = value


class RadarScene(Scene):
    """A ``sionna.rt.Scene`` with per-vertex differentiable radar parameters.

    Use :func:`load_scene` rather than this constructor.

    Parameters
    ----------
    mi_scene : mi.Scene
        Mitsuba scene holding one ``mi.Mesh`` per object
    objects : dict
        name -> :class:`MeshObject` (kept as ``mesh_objects``;
        Sionna's ``objects`` holds the ``SceneObject`` instances)
    frequency : float, optional
        carrier frequency [Hz] (default 77 GHz)
    radar : RadarConfig, optional
        its ``position`` [m] / ``orientation`` [rad] start the pose
    """

    def __init__(self, mi_scene: mi.Scene, objects: dict, frequency: float = DEFAULT_FREQUENCY_HZ,
                 radar=None):
        super().__init__(mi_scene=mi_scene)
        self.frequency = frequency
        self.mesh_objects: dict[str, MeshObject] = objects
        self.radar = radar
        self.sync()

    @property
    def radar(self):
        """The scene's radar (:class:`~sionna_mmir.radar.RadarConfig` or ``None``).

        Assigning one resets the pose tensors ``position`` / ``orientation``
        to its pose.
        """
        return self._radar

    @radar.setter
    def radar(self, radar):
        self._radar = radar
        pos = np.zeros(3) if radar is None else np.asarray(radar.position, dtype=float)
        ori = np.zeros(3) if radar is None else np.asarray(radar.orientation, dtype=float)
        self.position = _tensor(pos.reshape(3))
        self.orientation = _tensor(ori.reshape(3))

    def check_radar(self, radar) -> None:
        """Raise ``ConfigError`` if ``radar`` sits at another pose than the scene's radar."""
        own = self._radar
        if radar is None or radar is own or own is None:
            return
        same = (np.allclose(radar.position, own.position, atol=1e-9)
                and np.allclose(radar.orientation, own.orientation, atol=1e-12))
        if not same:
            raise ConfigError(
                "the radar given is at another pose than the scene's radar "
                f"({np.round(radar.position, 6).tolist()} vs "
                f"{np.round(own.position, 6).tolist()} m); the scene holds the pose: assign "
                "scene.radar = radar first")

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
        """Push vertex positions into Mitsuba (ray tracing uses them).

        Positions go through ``mi.traverse(scene)`` so the acceleration
        structure is rebuilt; the update is differentiable when the tensors
        have gradients enabled (AD variant).
        """
        scene_params = mi.traverse(self.mi_scene)
        for name, obj in self.mesh_objects.items():
            scene_params[f"{name}.vertex_positions"] = obj.vertex_positions.array
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


@dataclass
class ObjectData:
    """One object to build: validated mesh, material label, per-vertex materials.

    Parameters
    ----------
    mesh : TriMeshData
        :class:`~sionna_mmir.scene.mesh_io.TriMeshData`
    material : str
        label (an ITU-R P.2040 class or a free name)
    vertex_materials : numpy.ndarray
        ``[Nv, 6]`` (order
        :data:`~sionna_mmir.radio_materials.VERTEX_PARAMETER_NAMES`)
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
    built: dict[str, MeshObject] = {}
    scene_dict = {"type": "scene"}
    for name, obj in objects.items():
        if not isinstance(name, str) or not name or "." in name:
            raise InputValueError(f"load_scene: object name {name!r} must be a non-empty str without '.'")
        mats = np.asarray(obj.vertex_materials, dtype=np.float64)
        if mats.shape != (len(obj.mesh.vertices), 6) or not np.isfinite(mats).all():
            raise InputValueError(f"load_scene: object {name!r}: vertex materials must be finite "
                                  f"[{len(obj.mesh.vertices)}, 6], got {mats.shape}")
        material = VertexRadioMaterial(f"mmir-{name}", obj.material, _tensor(mats),
                                       obj.mesh.faces, frequency)
        scene_dict[name] = to_mitsuba_mesh(obj.mesh, name, material)
        built[name] = MeshObject(name, material, obj.mesh.faces,
                                 _tensor(obj.mesh.vertices), _tensor(obj.mesh.normals))
    mi_scene = mi.load_dict(scene_dict, optimize=False)
    return RadarScene(mi_scene, built, frequency=frequency, radar=radar)
