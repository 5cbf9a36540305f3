"""Plain Sionna RT 2.2 as the baseline, like for like with mmIR.

:class:`SionnaBaseline` renders the same scene with the same radar through
unmodified Sionna RT: one Sionna ``Scene`` with one mesh object per input
mesh, one Sionna radio material per object, Sionna's own ``PathSolver``, and
its paths turned into raw ADC by the same
:func:`~sionna_mmir.fmcw.synthesize_adc` the mmIR renderer uses, so the same
processing and metrics apply.  What Sionna can fit are per-object material
scalars; :meth:`SionnaBaseline.params` exposes them as unconstrained latents
and :meth:`SionnaBaseline.apply` pushes them (with their AD graph) into the
Sionna materials.

Settings and why (``describe()`` returns them for reports)
-----------------------------------------------------------

* **Materials.**  Each object gets its own radio material (so two concrete
  walls are fitted separately).  Where Sionna's ``ITURadioMaterial`` has an
  ITU-R P.2040 row covering the frequency (at 77 GHz: concrete,
  plasterboard, wood, glass, ceiling_board, chipboard, floorboard, metal) it
  is used as is, and its values are checked against the package's own table
  (:func:`~sionna_mmir.radio_materials.itu_material`); otherwise (never at
  77 GHz for the names the package accepts) a plain ``RadioMaterial`` with
  the package's values.  The ITU material's own frequency callback is
  evaluated once at ``frequency`` and then dropped: a Sionna ``Scene``
  attaches its materials at its default 3.5 GHz first (which raises for
  rows valid only at 50-100 GHz, e.g. floorboard), and a later frequency
  update must not overwrite fitted values.  Thickness starts at the package's
  construction defaults (:data:`~sionna_mmir.radio_materials.SURFACE_DEFAULTS`:
  0.2 m concrete, 12.5 mm plasterboard, 6 mm glass, ...), the same the mmIR
  scene starts from, instead of Sionna's 0.1 m for everything: Sionna's
  reflection coefficients are those of a slab of that thickness.
  ``scattering_coefficient`` starts at 0.3 (Sionna's default 0 would make
  diffuse reflection a no-op), Lambertian pattern, ``xpd_coefficient`` 0.
  Values at the edge of a latent's range are moved just inside it when the
  latents are first pushed: ``K_x`` and ``S`` to [1e-3, 1 - 1e-3] (so
  ``K_x`` starts at 1e-3: co-polar diffuse amplitude x 0.9995) and metal's
  ``eps_r = 1`` to ``1 + 1e-6``.

* **Antennas.**  One Sionna ``Transmitter`` per radar Tx element and one
  ``Receiver`` per Rx element (12 + 16 for the cascade), each at the
  element's exact scene position (``radar.position + R radar_frame_pos``,
  ``R = Rz(yaw) Ry(pitch) Rx(roll)``) with the radar's orientation, all with
  a single-element ``PlanarArray(1, 1, pattern="iso", polarization="V")``.
  Traced with ``synthetic_array=False`` every element is its own source /
  target, so every (Tx, Rx) pair gets its own exact path (delay, angles,
  coefficient), near field included: the MIMO phases are exact, not the
  plane-wave phase shifts of a synthetic array.  Cost: shoot-and-bounce runs
  ``samples_per_src`` rays from each of the ``n_tx`` sources, and every
  candidate is solved for each of the ``n_rx`` targets, i.e. ``n_tx`` times
  the rays and ``n_tx * n_rx`` times the image-method / field work of one
  synthetic Tx-Rx pair.  One device with an ``AntennaArray`` of the element
  positions and ``synthetic_array=False`` would trace exactly the same
  sources and targets (a ``PlanarArray`` cannot hold the irregular MIMO
  layout); per-element devices are simpler to index.  Isotropic elements:
  the radar's element pattern is not part of the like-for-like comparison
  (the mmIR renderer learns it separately).

* **Solver.**  ``PathSolver(deterministic=True)`` with ``loop_mode =
  "evaluated"`` (Sionna's default ``"symbolic"`` loops cannot be
  reverse-differentiated); ``los=False`` (monostatic radar: direct Tx->Rx
  coupling is not a scene path); ``max_depth=3``, ``samples_per_src=100_000``
  (Sionna's default is 1e6 rays from *one* source; here every Tx element is
  a source), specular and diffuse reflection on, wedge diffraction on,
  refraction off.  ``deterministic=True`` makes a fixed ``seed`` reproduce
  the same paths (Sionna's default candidate generator does not), needed for
  a stable loss and finite-difference checks; it costs up to ~2x per render.

* **Refraction off**: on the classroom catalog scene (2058 triangles,
  cascade, 100k rays per source) refraction added 432 refracted paths whose
  summed power is 31 dB under the specular paths', while the rays it spends
  on transmission events cut the paths found from 5839 to 1899 per pair.
  With it on, the event probabilities would also depend on the permittivity,
  so a fixed-seed Monte Carlo realisation would no longer be a smooth
  function of it.

* **Diffraction on** (Sionna 2.2: first-order UTD wedge diffraction).  It
  works at 77 GHz once creases share vertices: Sionna finds wedges only
  between faces sharing vertex indices, and the catalog scenes give pieces
  meeting at a crease their own vertices, so the scene is built with
  Sionna's ``remove_duplicate_vertices=True`` (no effect on flat-shaded
  reflection); without it Sionna found no diffracted path at all.  A
  monostatic radar sees an edge only where the ray meets it at right angles
  (the Keller cone contains the backscatter direction only then).  Checks:
  the vertical edge of a 45-degree-turned 0.5 m metal box at 2.66 m returns
  -122.5 dB through Sionna, against -122.3 dB from the Keller/UTD wedge
  coefficient (90-degree wedge, bisector backscatter, soft, n = 1.5) --
  appropriate at 77 GHz, where indoor edges are several Fresnel zones
  (``sqrt(lambda R)`` ~ 0.1 m) long; on the classroom scene 19k diffracted
  paths (~100 per pair) carry a summed power 14 dB under the specular and
  4 dB under the diffuse paths (hallway 14 dB, street 18 dB under the
  specular), i.e. edge returns reflections miss; material gradients through
  them match finite differences.  Cost: about +10-50 % per render.  Knife-edge
  ``edge_diffraction`` on free mesh borders stays off: the catalog's floors
  and ceilings are clipped to the field of view, so their borders are
  artificial.  Wedge geometry is detached in Sionna (no pose gradients; not
  learnable here anyway).

Differentiability
-----------------

Reverse-mode AD reaches ``relative_permittivity``, ``conductivity``,
``thickness`` (through the slab reflection coefficients of specular, diffuse
and diffracting interactions) and ``scattering_coefficient`` /
``xpd_coefficient`` (through ``sqrt(1 - S^2)`` on specular and ``S``, the
XPD matrix on diffuse interactions).  Some are zero in practice: the
thickness of a lossy thick slab (0.2 m concrete, metal) does not change its
reflection at 77 GHz.  Sionna records the probability with which shoot-and-bounce
sampled each interaction and divides by it *detached*: for
``scattering_coefficient`` (the only parameter the probabilities depend on
with refraction off, ``P(diffuse) = S^2``) the AD gradient is therefore the
gradient of the *expected* diffuse power (unbiased), not the derivative of one
Monte Carlo realisation, which a finite difference with a fixed seed
measures.  Geometry (vertices) is not a learnable input of the baseline:
Sionna's candidate vertices are detached, diffuse vertices carry no
geometric gradient, and the image method's plane offset is detached (see
``patches/README.md``, 0001 and 0005).
"""
from __future__ import annotations

import math
import os
import time

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radar.config import RadarConfig, rotation_matrix
from ..radio_materials.itu_table import SURFACE_DEFAULTS, itu_material
from ..scene.mesh_io import read_mesh, to_mitsuba_mesh
from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402  (after init_backend, on purpose)
import mitsuba as mi  # noqa: E402
import sionna.rt as rt  # noqa: E402
from sionna.rt.radio_materials.itu import ITU_MATERIALS_PROPERTIES  # noqa: E402

__all__ = ["SionnaBaseline", "PARAM_NAMES"]

#: Per-object material scalars Sionna exposes, in the order of :meth:`SionnaBaseline.params`.
PARAM_NAMES = ("relative_permittivity", "conductivity", "scattering_coefficient",
               "xpd_coefficient", "thickness")

#: Latent parametrisation of each scalar: ``value = f(latent)``.
LATENT_MAPS = {
    "relative_permittivity": "eps_r = 1 + exp(l)",
    "conductivity": "sigma = exp(l)  [S/m]",
    "scattering_coefficient": "S = sigmoid(l)",
    "xpd_coefficient": "K_x = sigmoid(l)",
    "thickness": "d = exp(l)  [m]",
}

# Floors / clips of the inverse maps (values at the edge of a parametrisation).
_EPS_MINUS_ONE_FLOOR = 1e-6      # metal: eps_r = 1 exactly -> 1 + 1e-6
_POSITIVE_FLOOR = 1e-12
_UNIT_CLIP = 1e-3                # S, K_x in [1e-3, 1 - 1e-3] (logit finite)

_PATTERNS = ("iso", "dipole", "hw_dipole", "tr38901")
_SCATTERING_PATTERNS = ("lambertian", "directive", "backscattering")


def _to_value(pname: str, latent):
    """Dr.Jit map latent -> physical value (keeps the AD graph)."""
    if pname == "relative_permittivity":
        return 1.0 + dr.exp(latent)
    if pname in ("conductivity", "thickness"):
        return dr.exp(latent)
    return dr.rcp(1.0 + dr.exp(-latent))          # sigmoid


def _to_latent(pname: str, value: float) -> float:
    """NumPy inverse of :func:`_to_value` (float64)."""
    v = float(value)
    if pname == "relative_permittivity":
        return math.log(max(v - 1.0, _EPS_MINUS_ONE_FLOOR))
    if pname in ("conductivity", "thickness"):
        return math.log(max(v, _POSITIVE_FLOOR))
    v = min(max(v, _UNIT_CLIP), 1.0 - _UNIT_CLIP)
    return math.log(v / (1.0 - v))


def _scalar(x) -> float:
    return float(np.asarray(dr.detach(x)).ravel()[0])


def _check_bool(name, v):
    if not isinstance(v, (bool, np.bool_)):
        raise ConfigError(f"SionnaBaseline: {name} must be a bool, got {v!r}")
    return bool(v)


def _check_int(name, v, lo):
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or int(v) < lo:
        raise ConfigError(f"SionnaBaseline: {name} must be an integer >= {lo}, got {v!r}")
    return int(v)


def _check_unit(name, v):
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ConfigError(f"SionnaBaseline: {name} must be a number in [0, 1], got {v!r}") from None
    if not (0.0 <= f <= 1.0):
        raise ConfigError(f"SionnaBaseline: {name} must be in [0, 1], got {v!r}")
    return f


def _check_inputs(where, meshes, materials, radar, frequency, scattering_pattern,
                  antenna_pattern) -> float:
    """Validate the baseline's inputs; returns the frequency [Hz]."""
    if not isinstance(radar, RadarConfig):
        raise ConfigError(f"{where}: radar must be a RadarConfig, got {type(radar).__name__}")
    if not isinstance(meshes, dict):
        raise InputValueError(f"{where}: meshes must be a dict name -> trimesh / path, "
                              f"got {type(meshes).__name__}")
    if not meshes:
        raise InputValueError(f"{where}: meshes is empty; give at least one object "
                              "(dict name -> trimesh.Trimesh or PLY/OBJ path)")
    if not isinstance(materials, dict):
        raise ConfigError(f"{where}: materials must be a dict name -> ITU material name, "
                          f"got {type(materials).__name__}")
    missing = sorted(set(meshes) - set(materials))
    extra = sorted(set(materials) - set(meshes))
    if missing:
        raise ConfigError(f"{where}: no material given for object(s) {missing}")
    if extra:
        raise ConfigError(f"{where}: materials given for unknown object(s) {extra}")
    try:
        f = float(frequency)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: frequency must be a number [Hz], "
                          f"got {frequency!r}") from None
    if not math.isfinite(f) or f <= 0:
        raise ConfigError(f"{where}: frequency must be a positive finite number [Hz], "
                          f"got {frequency!r}")
    if scattering_pattern not in _SCATTERING_PATTERNS:
        raise ConfigError(f"{where}: scattering_pattern must be one of "
                          f"{_SCATTERING_PATTERNS}, got {scattering_pattern!r}")
    if antenna_pattern not in _PATTERNS:
        raise ConfigError(f"{where}: antenna_pattern must be one of {_PATTERNS}, "
                          f"got {antenna_pattern!r}")
    return f


class SionnaBaseline:
    """Plain Sionna RT 2.2 on a scene + radar, rendered to raw FMCW ADC.

    Parameters
    ----------
    meshes : dict
        Object name -> ``trimesh.Trimesh`` or PLY/OBJ path (scene frame,
        metres).
    materials : dict
        Object name -> ITU-R P.2040 material valid at ``frequency`` (at
        77 GHz: concrete, metal, glass, wood, plasterboard, ceiling_board,
        chipboard, floorboard); one entry per mesh.
    radar : RadarConfig
        Elements, pose and waveform.
    frequency : float, optional
        Carrier for the materials and Sionna's wavelength [Hz] (77e9).
    max_depth : int, optional
        PathSolver ``max_depth`` (3).
    samples_per_src : int, optional
        Rays per source, i.e. per Tx element (100_000).
    specular_reflection : bool, optional
        Specular reflection (True).
    diffuse_reflection : bool, optional
        Diffuse reflection (True).
    refraction : bool, optional
        Refraction (False).
    diffraction : bool, optional
        Wedge diffraction (True, see the module docstring).
    edge_diffraction : bool, optional
        Knife-edge diffraction on free mesh borders (False: clipped floors /
        walls have artificial borders).
    seed : int, optional
        PathSolver seed used by :meth:`render` (0).
    scattering_coefficient : float, optional
        Initial ``S`` of every object (0.3).
    xpd_coefficient : float, optional
        Initial ``K_x`` of every object (0.0).
    scattering_pattern : {"lambertian", "directive", "backscattering"}, optional
        Sionna's registered patterns, with their default lobe parameters
        (default ``"lambertian"``).
    antenna_pattern : {"iso", "dipole", "hw_dipole", "tr38901"}, optional
        Element pattern of every Tx / Rx, vertical polarisation (default
        ``"iso"``).
    max_num_paths_per_src : int, optional
        PathSolver cap (Sionna's default 1_000_000).
    deterministic : bool, optional
        ``PathSolver(deterministic=True)`` (True).
    drop_degenerate : bool, optional
        Drop zero-area triangles instead of raising.

    Raises
    ------
    InputValueError
        No or bad meshes: empty dict, unreadable file, NaN / Inf vertices,
        degenerate triangles.
    ConfigError
        Unknown material or one invalid at ``frequency``, materials missing
        for / given for unknown objects, bad settings.
    """

    def __init__(self, meshes: dict, materials: dict, radar: RadarConfig, frequency: float = 77e9,
                 max_depth: int = 3, samples_per_src: int = 100_000,
                 specular_reflection: bool = True, diffuse_reflection: bool = True,
                 refraction: bool = False, diffraction: bool = True, seed: int = 0, *,
                 scattering_coefficient: float = 0.3, xpd_coefficient: float = 0.0,
                 scattering_pattern: str = "lambertian", antenna_pattern: str = "iso",
                 max_num_paths_per_src: int = 1_000_000, deterministic: bool = True,
                 edge_diffraction: bool = False, drop_degenerate: bool = False):
        where = "SionnaBaseline"
        f = _check_inputs(where, meshes, materials, radar, frequency, scattering_pattern,
                          antenna_pattern)
        self.radar = radar
        self.frequency = f
        self.max_depth = _check_int("max_depth", max_depth, 1)
        self.samples_per_src = _check_int("samples_per_src", samples_per_src, 1)
        self.max_num_paths_per_src = _check_int("max_num_paths_per_src", max_num_paths_per_src, 1)
        self.specular_reflection = _check_bool("specular_reflection", specular_reflection)
        self.diffuse_reflection = _check_bool("diffuse_reflection", diffuse_reflection)
        self.refraction = _check_bool("refraction", refraction)
        self.diffraction = _check_bool("diffraction", diffraction)
        self.edge_diffraction = _check_bool("edge_diffraction", edge_diffraction)
        self.deterministic = _check_bool("deterministic", deterministic)
        self.seed = _check_int("seed", seed, 0)
        s0 = _check_unit("scattering_coefficient", scattering_coefficient)
        kx0 = _check_unit("xpd_coefficient", xpd_coefficient)
        self.scattering_pattern = scattering_pattern
        self.antenna_pattern = antenna_pattern
        self._init_materials(where, meshes, materials, s0, kx0)
        self._init_scene(where, meshes, drop_degenerate)
        self._init_antennas(radar, antenna_pattern)
        # ---- solver
        self.solver = rt.PathSolver(deterministic=self.deterministic)
        self.solver.loop_mode = "evaluated"   # "symbolic" cannot be reverse-differentiated
        # ---- latents (float64 record of the current values) and initial push
        self._latents: dict[str, float] = {}
        for name, m in self.radio_materials.items():
            for pname in PARAM_NAMES:
                self._latents[f"{name}.{pname}"] = _to_latent(pname, _scalar(getattr(m, pname)))
        self.initial_values = {}
        self.apply(self.params())
        self.initial_values = self.values()
        self.last_paths = None
        self.last_render_s = None

    def _init_materials(self, where, meshes, materials, s0, kx0) -> None:
        """One Sionna ``RadioMaterial`` per object (validated before any mesh is read)."""
        self.object_names = list(meshes)
        self.material_names: dict[str, str] = {}
        self.material_source: dict[str, str] = {}
        self.radio_materials: dict = {}
        for name in self.object_names:
            if not isinstance(name, str) or not name or "." in name:
                raise InputValueError(f"{where}: object name {name!r} must be a non-empty str "
                                      "without '.'")
            mat = materials[name]
            if not isinstance(mat, str):
                raise ConfigError(f"{where}: material of {name!r} must be an ITU-R P.2040 name "
                                  f"(str), got {mat!r}")
            try:
                itu = itu_material(mat, self.frequency)   # unknown / out of band -> ConfigError
            except ConfigError as exc:
                raise ConfigError(f"{where}: object {name!r}: {exc}") from None
            self.material_names[name] = itu.name
            self.radio_materials[name] = self._radio_material(name, itu, s0, kx0)

    def _init_scene(self, where, meshes, drop_degenerate) -> None:
        """Meshes -> Mitsuba scene -> Sionna scene."""
        scene_dict = {"type": "scene"}
        self.num_triangles = 0
        for name, src in meshes.items():
            label = f"{where}: object {name!r}"
            if isinstance(src, (str, os.PathLike)):
                label += f" ({os.fspath(src)})"
            data = read_mesh(src, source=label, drop_degenerate=drop_degenerate)
            self.num_triangles += len(data.faces)
            scene_dict[name] = to_mitsuba_mesh(data, name, self.radio_materials[name])
        # remove_duplicate_vertices: pieces of one object meeting at a crease may
        # have their own vertices; Sionna finds diffracting wedges only between
        # faces sharing vertex indices.  No effect on (flat-shaded) reflection.
        self.scene = rt.Scene(mi_scene=mi.load_dict(scene_dict, optimize=False),
                              remove_duplicate_vertices=True)
        self.scene.frequency = self.frequency

    def _init_antennas(self, radar, antenna_pattern) -> None:
        """One Sionna device per element, at its exact scene position."""
        self.scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1,
                                             pattern=antenna_pattern, polarization="V")
        self.scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1,
                                             pattern=antenna_pattern, polarization="V")
        rot = rotation_matrix(radar.orientation)
        self.tx_scene_positions = radar.position[None, :] + radar.tx_positions @ rot.T
        self.rx_scene_positions = radar.position[None, :] + radar.rx_positions @ rot.T
        ori = mi.Point3f(*(float(v) for v in radar.orientation))
        for i, p in enumerate(self.tx_scene_positions):
            self.scene.add(rt.Transmitter(f"tx{i}", position=mi.Point3f(*(float(v) for v in p)),
                                          orientation=ori))
        for j, p in enumerate(self.rx_scene_positions):
            self.scene.add(rt.Receiver(f"rx{j}", position=mi.Point3f(*(float(v) for v in p)),
                                       orientation=ori))

    # ------------------------------------------------------------ materials
    def _radio_material(self, name, itu, s0, kx0):
        """Sionna's ITURadioMaterial where its table covers ``frequency``, else RadioMaterial."""
        f_ghz = self.frequency / 1e9
        thickness = SURFACE_DEFAULTS[itu.name].thickness
        common = dict(thickness=thickness, scattering_coefficient=s0, xpd_coefficient=kx0,
                      scattering_pattern=self.scattering_pattern)
        bands = ITU_MATERIALS_PROPERTIES.get(itu.name, {})
        if any(lo <= f_ghz <= hi for lo, hi in bands):
            self.material_source[name] = "sionna.rt.ITURadioMaterial"
            m = rt.ITURadioMaterial(name=f"baseline-{name}", itu_type=itu.name, **common)
            # Evaluate Sionna's own ITU callback at our frequency, then freeze the
            # values: a Scene attaches its materials at Sionna's default 3.5 GHz
            # first (which raises for 50-100 GHz rows such as floorboard), and a
            # later frequency update must not overwrite fitted values.
            eps, sigma = m.frequency_update_callback(mi.Float(self.frequency))
            m.frequency_update_callback = None
            m.relative_permittivity = eps
            m.conductivity = sigma
            self._check_against_table(name, m, itu)
            return m
        self.material_source[name] = "sionna.rt.RadioMaterial (sionna_mmir ITU-R P.2040 table)"
        return rt.RadioMaterial(name=f"baseline-{name}", relative_permittivity=itu.eps_real,
                                conductivity=itu.conductivity, **common)

    def _check_against_table(self, name, m, itu):
        eps, sig = _scalar(m.relative_permittivity), _scalar(m.conductivity)
        if not (np.isclose(eps, itu.eps_real, rtol=1e-4)
                and np.isclose(sig, itu.conductivity, rtol=1e-4)):
            raise ConfigError(f"SionnaBaseline: Sionna's ITU values for {itu.name!r} at "
                              f"{self.frequency / 1e9:g} GHz (eps_r {eps:g}, sigma {sig:g} S/m) "
                              f"differ from ITU-R P.2040-3 (eps_r {itu.eps_real:g}, "
                              f"sigma {itu.conductivity:g} S/m)")

    # --------------------------------------------------------------- params
    def params(self) -> dict:
        """Current latents: ``{"<object>.<param>": mi.Float (1 entry)}``, fresh and detached.

        ``<param>`` is one of :data:`PARAM_NAMES`; the latent maps to the
        value by :data:`LATENT_MAPS` (``eps_r = 1 + exp(l)``, ``sigma =
        exp(l)``, ``S = sigmoid(l)``, ``K_x = sigmoid(l)``, ``d = exp(l)``).
        Enable gradients on those to fit and pass them to :meth:`apply`.
        """
        return {k: mi.Float(v) for k, v in self._latents.items()}

    def apply(self, latents: dict) -> None:
        """Push latents (with their AD graph) into the Sionna materials.

        ``latents``: any subset of :meth:`params`'s keys -> ``mi.Float`` (or a
        number); the others keep their current values.  Unknown keys or
        non-finite values raise :class:`~sionna_mmir.errors.InputValueError`.
        Call before :meth:`render`; gradients of the render reach these
        latents.
        """
        if not isinstance(latents, dict):
            raise InputValueError(f"SionnaBaseline.apply: latents must be a dict, "
                                  f"got {type(latents).__name__}")
        staged = []
        for key, lat in latents.items():
            if key not in self._latents:
                raise InputValueError(f"SionnaBaseline.apply: unknown parameter {key!r}; "
                                      f"keys are '<object>.<param>' with objects "
                                      f"{self.object_names} and params {list(PARAM_NAMES)}")
            if not isinstance(lat, mi.Float):
                lat = mi.Float(lat)
            if dr.width(lat) != 1:
                raise InputValueError(f"SionnaBaseline.apply: {key!r} must hold one value, "
                                      f"got {dr.width(lat)}")
            v = _scalar(lat)
            if not math.isfinite(v):
                raise InputValueError(f"SionnaBaseline.apply: {key!r} is not finite ({v})")
            staged.append((key, lat, v))
        for key, lat, v in staged:
            name, pname = key.split(".", 1)
            setattr(self.radio_materials[name], pname, _to_value(pname, lat))
            self._latents[key] = v

    def set_values(self, values: dict) -> None:
        """Set physical values ``{"<object>.<param>": float}`` (the inverse of :meth:`values`).

        Each value goes through the inverse of its :data:`LATENT_MAPS` entry
        (with the floors / clips of the first push) and :meth:`apply`.
        """
        if not isinstance(values, dict):
            raise InputValueError(f"SionnaBaseline.set_values: values must be a dict, "
                                  f"got {type(values).__name__}")
        latents = {}
        for key, v in values.items():
            pname = key.split(".", 1)[-1]
            if pname not in PARAM_NAMES:
                raise InputValueError(f"SionnaBaseline.set_values: unknown parameter {key!r}; "
                                      f"params are {list(PARAM_NAMES)}")
            latents[key] = _to_latent(pname, v)
        self.apply(latents)

    def values(self) -> dict:
        """Current physical values ``{"<object>.<param>": float}`` (detached)."""
        return {f"{n}.{p}": _scalar(getattr(m, p))
                for n, m in self.radio_materials.items() for p in PARAM_NAMES}

    # --------------------------------------------------------------- render
    def trace(self, seed: int | None = None):
        """Run Sionna's ``PathSolver`` with the baseline's settings; returns ``sionna.rt.Paths``."""
        seed = self.seed if seed is None else _check_int("seed", seed, 0)
        return self.solver(self.scene, max_depth=self.max_depth,
                           max_num_paths_per_src=self.max_num_paths_per_src,
                           samples_per_src=self.samples_per_src, synthetic_array=False,
                           los=False, specular_reflection=self.specular_reflection,
                           diffuse_reflection=self.diffuse_reflection,
                           refraction=self.refraction, diffraction=self.diffraction,
                           edge_diffraction=self.edge_diffraction,
                           diffraction_lit_region=True, seed=seed)

    def pair_paths(self, paths):
        """Sionna paths -> per-pair ``(a_re, a_im, tau)`` ``mi.TensorXf [n_tx, n_rx, P]``.

        Sionna's ``a``, ``tau`` and ``valid`` are ``[num_rx, 1, num_tx, 1,
        P]`` (one element per device); they are gathered differentiably into
        the radar's ``[tx, rx, P]`` order.  Invalid paths get zero amplitude
        and delay.  The amplitude is conjugated: Sionna's passband response is
        ``h(f) = sum a_s exp(-j 2 pi f tau)`` while the FMCW beat signal is
        ``s[k] = sum a exp(+j 2 pi f_k tau)``, so ``s = conj(h(f_k))`` and
        ``a = conj(a_s)``.
        """
        T, R = self.radar.num_tx, self.radar.num_rx
        a_re, a_im = paths.a
        tau = paths.tau
        shape = tuple(tau.shape)
        if shape[:4] != (R, 1, T, 1):
            raise InputValueError(f"SionnaBaseline.pair_paths: expected paths of shape "
                                  f"[{R}, 1, {T}, 1, P], got {list(shape)}")
        P = int(shape[4])
        if P == 0:
            z = dr.zeros(mi.TensorXf, (T, R, 1))
            return z, dr.zeros(mi.TensorXf, (T, R, 1)), dr.zeros(mi.TensorXf, (T, R, 1))
        t, r, p = np.meshgrid(np.arange(T), np.arange(R), np.arange(P), indexing="ij")
        idx = mi.UInt32(((r * T + t) * P + p).ravel().astype(np.uint32))
        valid = dr.gather(mi.Bool, paths.valid.array, idx)
        are = dr.gather(mi.Float, a_re.array, idx)
        aim = dr.gather(mi.Float, a_im.array, idx)
        tt = dr.gather(mi.Float, tau.array, idx)
        ok = valid & dr.isfinite(are) & dr.isfinite(aim) & dr.isfinite(tt) & (tt >= 0)
        are = dr.select(ok, are, 0.0)
        aim = dr.select(ok, -aim, 0.0)              # conj
        tt = dr.select(ok, tt, 0.0)
        return (mi.TensorXf(are, (T, R, P)), mi.TensorXf(aim, (T, R, P)),
                mi.TensorXf(tt, (T, R, P)))

    def render(self, seed: int | None = None):
        """Raw ADC of one frame: ``DrAdc`` (``real``, ``imag`` ``mi.TensorXf
        [n_tx, n_rx, num_chirps, num_samples]``) inside the AD graph.

        Traces with :meth:`trace` (``seed`` default: the constructor's),
        converts with :meth:`pair_paths` and synthesises with
        :func:`~sionna_mmir.fmcw.synthesize_adc` (static scene).  The Sionna
        paths are kept in ``last_paths``, the wall time in ``last_render_s``.
        """
        from ..fmcw.synthesize import synthesize_adc

        t0 = time.perf_counter()
        paths = self.trace(seed)
        a_re, a_im, tau = self.pair_paths(paths)
        adc = synthesize_adc(self.radar, (a_re, a_im), tau)
        self.last_paths = paths
        self.last_render_s = time.perf_counter() - t0
        return adc

    # ------------------------------------------------------------- describe
    def describe(self) -> dict:
        """The exact settings: Sionna version, solver call, antennas, materials."""
        import importlib.metadata

        try:
            version = importlib.metadata.version("sionna-rt")
        except importlib.metadata.PackageNotFoundError:  # pragma: no cover
            version = "unknown"
        return {
            "renderer": "sionna.rt (unmodified)",
            "sionna_rt_version": version,
            "mitsuba_variant": mi.variant(),
            "frequency_hz": self.frequency,
            "solver": {
                "class": "sionna.rt.PathSolver",
                "deterministic": self.deterministic,
                "loop_mode": self.solver.loop_mode,
                "max_depth": self.max_depth,
                "samples_per_src": self.samples_per_src,
                "max_num_paths_per_src": self.max_num_paths_per_src,
                "synthetic_array": False,
                "los": False,
                "specular_reflection": self.specular_reflection,
                "diffuse_reflection": self.diffuse_reflection,
                "refraction": self.refraction,
                "diffraction": self.diffraction,
                "edge_diffraction": self.edge_diffraction,
                "diffraction_lit_region": True,
                "seed": self.seed,
            },
            "antennas": {
                "layout": "one sionna.rt.Transmitter per radar Tx element, one Receiver "
                          "per Rx element, at the exact scene positions",
                "num_tx": self.radar.num_tx,
                "num_rx": self.radar.num_rx,
                "array": f"PlanarArray(num_rows=1, num_cols=1, pattern={self.antenna_pattern!r}, "
                         "polarization='V')",
                "orientation_rad": [float(v) for v in self.radar.orientation],
                "tx_scene_positions_m": self.tx_scene_positions.tolist(),
                "rx_scene_positions_m": self.rx_scene_positions.tolist(),
            },
            "adc": "sionna_mmir.fmcw.synthesize_adc(radar, conj(paths.a), paths.tau), static",
            "materials": {
                name: {"itu": self.material_names[name], "source": self.material_source[name],
                       "scattering_pattern": self.scattering_pattern,
                       "initial": {p: self.initial_values.get(f"{name}.{p}") for p in PARAM_NAMES}}
                for name in self.object_names},
            "learnable": {p: LATENT_MAPS[p] for p in PARAM_NAMES},
            "num_objects": len(self.object_names),
            "num_triangles": self.num_triangles,
            "notes": [
                "loop_mode 'evaluated': Sionna's default 'symbolic' loops cannot be "
                "reverse-differentiated",
                "los=False: direct Tx->Rx coupling of a monostatic radar is not a scene path",
                "diffuse-event probabilities are detached in Sionna: the AD gradient w.r.t. "
                "scattering_coefficient is that of the expected diffuse power",
                "Sionna Scene built with remove_duplicate_vertices=True: Sionna finds "
                "diffracting wedges only between faces sharing vertices",
                "wedge diffraction on (first-order UTD; monostatic returns only where the "
                "ray meets an edge at right angles; ~14 dB under the specular paths on the "
                "classroom scene); knife-edge diffraction on free borders off (clipped "
                "floors have artificial borders)",
                "refraction off: ~31 dB under the specular paths, and it spends rays",
            ],
        }

    def __repr__(self) -> str:
        return (f"SionnaBaseline({len(self.object_names)} objects, {self.num_triangles} "
                f"triangles, radar {self.radar.name!r} {self.radar.num_tx}x{self.radar.num_rx}, "
                f"max_depth={self.max_depth}, samples_per_src={self.samples_per_src}, "
                f"diffuse={self.diffuse_reflection}, diffraction={self.diffraction})")
