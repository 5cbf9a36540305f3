"""Sionna RT scenes in: ``sionna.rt.Scene`` or Mitsuba XML -> :class:`RadarScene`.

:func:`load_sionna_scene` (reached through
:func:`sionna_mmir.load_scene <sionna_mmir.scene.load.load_scene>`) accepts

* a ``sionna.rt.Scene`` (e.g. ``sionna.rt.load_scene(sionna.rt.scene.box)``,
  objects moved, rotated or added by hand included),
* the path of a Sionna / Mitsuba XML scene, among them Sionna's built-in
  scenes (``sionna.rt.scene.simple_street_canyon``, ``floor_wall``, ``box``,
  ...: these constants are XML paths); it is read by
  ``sionna.rt.load_scene(path, merge_shapes=merge_shapes)``.

Geometry
--------
Each Sionna object becomes one object of the same name (``.`` replaced by
``_``), except that the shapes Sionna merges (``merge_shapes``), which it
names ``no-name-<n>`` from a counter that runs across loads, are named
``merged-<material name>`` so that every load of a file gives the same names.  Its vertices are the Mitsuba mesh's, which Sionna keeps in world
coordinates: the XML ``to_world`` transforms and any later
``obj.position`` / ``orientation`` / ``scaling`` are already applied.
``shading`` picks the shading normals:

==========  ==============================================================
"sionna"    (default) what Sionna renders: a mesh with vertex normals
            (``face_normals="false"``) keeps its vertices and normals; a
            mesh without (``face_normals="true"``, all built-in scenes) is
            flat-shaded, three vertices per face
            (:func:`~sionna_mmir.scaffold.shading.flat_shaded`)
"shared"    Sionna's vertices as they are (vertex counts equal Sionna's);
            normals the mesh's, else averaged over the adjacent faces
"flat"      every face flat
"auto"      :func:`~sionna_mmir.scaffold.shading.auto_shaded`
==========  ==============================================================

Materials (the 77 GHz policy)
-----------------------------
Materials are evaluated at ``frequency`` (default 77 GHz), not at
``sionna_scene.frequency`` (Sionna's default is 3.5 GHz).

* ``ITURadioMaterial``: its ``itu_type`` is evaluated with the package's
  ITU-R P.2040-3 Table 3 (:mod:`~sionna_mmir.radio_materials.itu_table`);
  the four types Sionna adds from P.2040-4 (``asphalt_concrete``,
  ``vinyl_tile``, ``carpet_tile``, ``clear_acrylic``) with Sionna's own rows.
  Roughness and the KA/SPM blend (``sigma_h``, ``l_c``, ``tau``) are the
  type's :data:`~sionna_mmir.radio_materials.SURFACE_DEFAULTS` (for the four
  P.2040-4 types those of :data:`SURFACE_ANALOGUES`); the thickness is the
  Sionna material's ``thickness``.  Sionna's current ``relative_permittivity``
  / ``conductivity`` (evaluated at the Sionna scene's frequency) are not used.
* Out of band.  Several P.2040 fits stop below 77 GHz (brick, plywood,
  vinyl / carpet tile and asphalt concrete at 40 GHz, marble at 60 GHz, the
  grounds at 10 GHz; clear acrylic starts at 110 GHz).  The policy is to
  **extrapolate the power law** ``eps' = a f^b``, ``sigma = c f^d`` of the
  nearest tabulated band and say so:

  ======================  ==================================================
  ``allow_out_of_band``
  ``None`` (default)      extrapolate, with an :class:`OutOfBandMaterialWarning`
                          naming the object, the material, the frequency and
                          the tabulated range
  ``True``                extrapolate silently
  ``False``               raise :class:`~sionna_mmir.errors.ConfigError`
  ======================  ==================================================

  At 77 GHz brick becomes ``eps = 3.91 - 0.0111j`` (``sigma`` 0.048 S/m) and
  marble ``eps = 7.074 - 0.0717j`` (``sigma`` 0.31 S/m): the permittivities
  of these fits are frequency-independent (``b = 0``), only the loss term is
  extrapolated.  To use another value instead, map the object (or every
  object of a Sionna material) with ``materials=``.
* A plain ``RadioMaterial``: ``relative_permittivity`` and ``conductivity``
  (through its ``frequency_update_callback`` at ``frequency`` when it has
  one), ``thickness``; roughness from ``SURFACE_DEFAULTS["concrete"]``.
* Anything else (e.g. ``AbsorberRadioMaterial``, a custom material class)
  raises ``ConfigError`` naming the object; map it with ``materials=``.

``materials`` maps an object name, or a Sionna material name (every object
using it), to an ITU-R P.2040 class name of the package's table or to the six
per-vertex values ``[eps_real, eps_imag, sigma_h, l_c, tau, thickness]``;
object names win over material names.  Sionna's scattering and XPD
coefficients and scattering patterns have no counterpart here and are
ignored (mmIR's BSDF models roughness from ``sigma_h`` / ``l_c``).

When ``radar`` is not given and the Sionna scene has one ``Transmitter``, the
scene's radar is :func:`~sionna_mmir.radar.sionna_devices.radar_from_sionna`
of it (pose from the transmitter; MMWCAS waveform).
"""
from __future__ import annotations

import os
import re
import warnings

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radio_materials.itu_table import (ITU_TABLE, SURFACE_DEFAULTS, eps_imag_from_conductivity,
                                         itu_material)
from .mesh_io import TriMeshData, read_mesh

#: surface defaults for Sionna's P.2040-4 types absent from the package's table
SURFACE_ANALOGUES = {"asphalt_concrete": "concrete", "vinyl_tile": "floorboard",
                     "carpet_tile": "ceiling_board", "clear_acrylic": "glass"}
#: roughness defaults of plain (non-ITU) Sionna ``RadioMaterial`` instances
GENERIC_SURFACE = "concrete"
SHADINGS = ("sionna", "shared", "flat", "auto")


class OutOfBandMaterialWarning(UserWarning):
    """An ITU-R P.2040 fit was extrapolated outside its tabulated band."""


def is_sionna_source(obj) -> bool:
    """True for a ``sionna.rt.Scene`` (not a ``RadarScene``) or an ``.xml`` path."""
    if isinstance(obj, (str, os.PathLike)):
        return os.fspath(obj).lower().endswith(".xml")
    from sionna.rt import Scene

    from .scene import RadarScene

    return isinstance(obj, Scene) and not isinstance(obj, RadarScene)


def read_sionna_scene(path, merge_shapes: bool = True):
    """``sionna.rt.load_scene(path)`` with the package's errors.

    Raises ``InputValueError`` (``<path>: ...``) for a missing or unreadable
    file and ``ConfigError`` for a material Sionna rejects.
    """
    import sionna.rt as rt

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputValueError(f"{path}: scene file does not exist")
    try:
        return rt.load_scene(path, merge_shapes=merge_shapes)
    except (ValueError, TypeError, RuntimeError, SyntaxError, OSError) as exc:  # XML ParseError
        text = " ".join(str(exc).split())
        cls = ConfigError if "material" in text.lower() else InputValueError
        raise cls(f"{path}: Sionna cannot load the scene: {text}") from exc


def load_sionna_scene(source, frequency: float = 77e9, materials: dict | None = None,
                      radar=None, drop_degenerate: bool = False,
                      allow_out_of_band: bool | None = None, shading: str = "sionna",
                      merge_shapes: bool = True):
    """Convert a Sionna scene (object or XML path) into a :class:`RadarScene`.

    Parameters
    ----------
    source : sionna.rt.Scene or str
        ``sionna.rt.Scene`` or XML path
    frequency : float, optional
        carrier frequency [Hz]; materials are evaluated here
    materials : dict, optional
        ``dict`` object or Sionna material name -> ITU class
        name or six per-vertex values (see module docstring)
    radar : RadarConfig, optional
        default: from the scene's transmitter
        if it has exactly one, else none
    drop_degenerate : bool, optional
        drop triangles < 1e-12 m^2 instead of raising
    allow_out_of_band : bool, optional
        ``None`` | ``True`` | ``False``: the 77 GHz policy
        (module docstring)
    shading : {"sionna", "shared", "flat", "auto"}, optional
        shading normals of the imported meshes
    merge_shapes : bool, optional
        XML paths: Sionna's ``merge_shapes`` (default True, as
        ``sionna.rt.load_scene``)

    Returns
    -------
    RadarScene
    """
    from .scene import ObjectData, scene_from_objects

    if shading not in SHADINGS:
        raise ConfigError(f"load_scene: shading must be one of {SHADINGS}, got {shading!r}")
    if isinstance(source, (str, os.PathLike)):
        where, sc = os.fspath(source), read_sionna_scene(source, merge_shapes)
    else:
        where, sc = "sionna scene", source
    if not sc.objects:
        raise InputValueError(f"{where}: the scene has no shapes")
    overrides = _check_overrides(materials, sc, where)
    objects = {}
    for sname, obj in sc.objects.items():
        name = object_name(sname, obj)
        if name in objects:
            raise InputValueError(f"{where}: objects {sname!r} and another map to the name {name!r}")
        mesh = object_mesh(obj, shading, drop_degenerate, f"{where}: object {sname!r}")
        label, vparams = _object_material(obj, overrides, frequency, allow_out_of_band,
                                          f"{where}: object {sname!r}")
        objects[name] = ObjectData(mesh, label, np.tile(vparams, (len(mesh.vertices), 1)))
    if radar is None and len(sc.transmitters) == 1:
        from ..radar.sionna_devices import radar_from_sionna

        radar = radar_from_sionna(sc)
    return scene_from_objects(objects, frequency=frequency, radar=radar)


def object_name(sname: str, obj) -> str:
    """Object name of Sionna object ``sname`` (see "Geometry" above)."""
    if re.fullmatch(r"no-name-\d+", sname):
        sname = f"merged-{obj.radio_material.name}"
    return sname.replace(".", "_")


def object_mesh(obj, shading: str = "sionna", drop_degenerate: bool = False,
                where: str = "object") -> TriMeshData:
    """World-frame mesh of a Sionna ``SceneObject`` (see "Geometry" above)."""
    import mitsuba as mi
    import trimesh

    from ..scaffold.shading import auto_shaded, flat_shaded

    if not isinstance(obj.mi_mesh, mi.Mesh):
        raise InputValueError(f"{where}: is a {type(obj.mi_mesh).__name__} shape; only "
                              "triangle meshes are supported")
    verts, faces, normals = _mesh_arrays(obj.mi_mesh)
    has_normals = normals is not None
    kw = {"vertex_normals": normals} if has_normals else {}
    tm = trimesh.Trimesh(verts, faces, process=False, **kw)
    mode = ("shared" if has_normals else "flat") if shading == "sionna" else shading
    if mode == "flat":
        tm = flat_shaded(tm)
    elif mode == "auto":
        tm = auto_shaded({"mesh": tm})["mesh"]
    return read_mesh(tm, source=where, drop_degenerate=drop_degenerate)


def _mesh_arrays(mesh):
    """``(vertices [V, 3], faces [F, 3], normals [V, 3] or None)`` in world
    coordinates.  Sionna's PLY / OBJ meshes hold world positions; Mitsuba's
    analytic meshes (``rectangle``, ``cube``) hold local ones and a
    ``to_world`` transform until a scene applies it: the transform is applied
    when the buffer's bounding box is not the shape's (world) one."""
    import mitsuba as mi

    params = mi.traverse(mesh)
    faces = np.array(mesh.faces_buffer(), dtype=np.int64).reshape(-1, 3)
    verts = np.array(mesh.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
    normals = (np.array(mesh.vertex_normals_buffer(), dtype=np.float64).reshape(-1, 3)
               if mesh.has_vertex_normals() else None)
    box = mesh.bbox()
    world = np.array([list(box.min), list(box.max)], dtype=np.float64).reshape(2, 3)
    local = len(verts) and not np.allclose([verts.min(0), verts.max(0)], world, atol=1e-5)
    if local and "vertex_positions" not in params and "to_world" in params:
        m = np.array(params["to_world"].matrix, dtype=np.float64).reshape(4, 4)
        verts = verts @ m[:3, :3].T + m[:3, 3]
        if normals is not None:
            normals = normals @ np.linalg.inv(m[:3, :3])
    return verts, faces, normals


def _check_overrides(materials, sc, where) -> dict:
    overrides = dict(materials or {})
    known = (set(sc.objects) | {object_name(n, o) for n, o in sc.objects.items()}
             | {o.radio_material.name for o in sc.objects.values()})
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ConfigError(f"{where}: materials given for unknown objects / materials {unknown}; "
                          f"objects {sorted(sc.objects)}")
    return overrides


def _object_material(obj, overrides, frequency, allow_out_of_band, where):
    mat = obj.radio_material
    choice = next((overrides[k] for k in (obj.name, object_name(obj.name, obj), mat.name)
                   if k in overrides), None)
    if choice is None:
        return material_parameters(mat, frequency, allow_out_of_band, where)
    if isinstance(choice, str):
        m = itu_material(choice, frequency, allow_out_of_band=True)
        if not m.in_band:
            _out_of_band(where, m.name, [m.valid_range_ghz], frequency, allow_out_of_band)
        return m.name, _vector(m.eps_real, m.eps_imag, SURFACE_DEFAULTS[m.name],
                               SURFACE_DEFAULTS[m.name].thickness)
    vals = np.asarray(choice, dtype=np.float64)
    if vals.shape != (6,) or not np.isfinite(vals).all():
        raise ConfigError(f"{where}: materials= value must be an ITU class name or six finite "
                          f"numbers [eps_real, eps_imag, sigma_h, l_c, tau, thickness], "
                          f"got {choice!r}")
    return str(mat.name), vals


def material_parameters(mat, frequency: float = 77e9, allow_out_of_band: bool | None = None,
                        where: str = "material") -> tuple[str, np.ndarray]:
    """``(label, [6] per-vertex values)`` of a Sionna radio material at ``frequency``.

    Parameters
    ----------
    mat : sionna.rt.RadioMaterial
        ``ITURadioMaterial`` or ``RadioMaterial``
    frequency : float, optional
        frequency [Hz]
    allow_out_of_band : bool, optional
        the 77 GHz policy (module docstring)
    where : str, optional
        prefix of messages (object / file)

    Returns
    -------
    label : str
        ITU type or material name
    values : numpy.ndarray
        float64 (6,): ``[eps_real, eps_imag, sigma_h [m],
        l_c [m], tau, thickness [m]]``
    """
    from sionna.rt import ITURadioMaterial, RadioMaterial

    thickness = _scalar(mat.thickness) if hasattr(mat, "thickness") else None
    if isinstance(mat, ITURadioMaterial):
        eps_real, sigma, surface = _itu_values(mat.itu_type, frequency, allow_out_of_band, where)
        eps_imag = float(eps_imag_from_conductivity(sigma, frequency))
        return mat.itu_type, _vector(eps_real, eps_imag, surface, thickness)
    if isinstance(mat, RadioMaterial):
        cb = mat.frequency_update_callback
        if cb is not None:
            eps_real, sigma = (_scalar(v) for v in cb(float(frequency)))
        else:
            eps_real, sigma = _scalar(mat.relative_permittivity), _scalar(mat.conductivity)
        eps_imag = float(eps_imag_from_conductivity(sigma, frequency))
        return str(mat.name), _vector(eps_real, eps_imag, SURFACE_DEFAULTS[GENERIC_SURFACE],
                                      thickness)
    raise ConfigError(f"{where}: radio material {getattr(mat, 'name', '?')!r} of type "
                      f"{type(mat).__name__} has no permittivity to map; give it one with "
                      "materials={name: 'concrete'} (an ITU-R P.2040 class) or six values")


def _itu_values(itu_type, frequency, allow_out_of_band, where):
    """``(eps', sigma [S/m], SurfaceDefaults)`` of an ITU type, with the policy."""
    f_ghz = float(frequency) / 1e9
    if itu_type in ITU_TABLE:
        m = itu_material(itu_type, frequency, allow_out_of_band=True)
        if not m.in_band:
            bands = [(r.f_min_ghz, r.f_max_ghz) for r in ITU_TABLE[itu_type]]
            _out_of_band(where, itu_type, bands, frequency, allow_out_of_band)
        return m.eps_real, m.conductivity, SURFACE_DEFAULTS[m.name]
    from sionna.rt.radio_materials.itu import ITU_MATERIALS_PROPERTIES

    rows = ITU_MATERIALS_PROPERTIES.get(itu_type)
    if rows is None or itu_type not in SURFACE_ANALOGUES:
        raise ConfigError(f"{where}: unknown ITU material type {itu_type!r}")
    band = next((b for b in rows if b[0] <= f_ghz <= b[1]), None)
    if band is None:
        _out_of_band(where, itu_type, list(rows), frequency, allow_out_of_band)
        band = min(rows, key=lambda b: min(abs(f_ghz - b[0]), abs(f_ghz - b[1])))
    a, b, c, d = rows[band]
    return a * f_ghz ** b, c * f_ghz ** d, SURFACE_DEFAULTS[SURFACE_ANALOGUES[itu_type]]


def _out_of_band(where, name, bands, frequency, allow_out_of_band):
    f_ghz = float(frequency) / 1e9
    ranges = ", ".join(f"{lo:g}-{hi:g} GHz" for lo, hi in bands)
    if allow_out_of_band is False:
        raise ConfigError(f"{where}: ITU-R P.2040 material {name!r} is tabulated for {ranges} "
                          f"only, not {f_ghz:g} GHz; pass allow_out_of_band=None/True to "
                          "extrapolate its fit, or map it with materials={...}")
    if allow_out_of_band is None:
        warnings.warn(f"{where}: ITU-R P.2040 material {name!r} is tabulated for {ranges}; "
                      f"its fit is extrapolated to {f_ghz:g} GHz (pass materials= to choose "
                      "another, allow_out_of_band=True to silence)",
                      OutOfBandMaterialWarning, stacklevel=4)


def _vector(eps_real, eps_imag, surface, thickness) -> np.ndarray:
    d = surface.thickness if thickness is None else thickness
    return np.array([eps_real, eps_imag, surface.sigma_h, surface.l_c, surface.tau, d],
                    dtype=np.float64)


def _scalar(v) -> float:
    return float(np.asarray(v, dtype=np.float64).reshape(-1)[0])
