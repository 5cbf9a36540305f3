"""Dataset spec (JSON): parsing, validation and the per-frame plan.

A spec::

    {
      "scenes": ["sionna:floor_wall",                       # a Sionna built-in scene
                 "street.xml",                              # Sionna / Mitsuba XML
                 "fit_out/scene_mmir.ply",                  # fitted scene PLY
                 {"name": "lab", "meshes": {"wall": "wall.ply", "desk": "desk.obj"},
                  "materials": {"wall": "concrete", "desk": "wood"}}],
      "radars": ["awr1843", {"preset": "mmwcas", "chirps": 4},
                 "coloradar_calib",                         # a ColoRadar calib folder (cascade)
                 {"coloradar": "calib", "sensor": "single_chip"}],
      "poses": {"type": "line", "start": [0, 0, 1], "direction": [1, 0, 0],
                "speed": 2.0, "frames": 200, "frame_period": 0.1},
      "solver": {"num_rays": 20000, "max_depth": 2},
      "seed": 0,
      "frames_per_shard": 50
    }

Relative paths are relative to the spec file.  Scene entries may also carry
``"allow_out_of_band"`` (see :func:`~sionna_mmir.scene.load_scene`); a plain
mesh path is one object named by its file stem, ``"concrete"`` unless
``materials`` says otherwise.  ``poses``: see :mod:`.poses`.  Every
(scene, radar, pose) triple is one frame, in that nesting order; frame ``i``
renders with seed ``seed + i``.

Every problem raises :class:`~sionna_mmir.errors.ConfigError` as
``<path>: <problem>``, the path being the offending file (a scene or calib
folder that does not exist) or the spec.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os

from ..errors import ConfigError
from .poses import poses_from_spec

RADAR_PRESETS = ("mmwcas", "awr1843", "dense")
SOLVER_OPTIONS = {"num_rays": int, "max_depth": int, "cone_angle_deg": (int, float),
                  "coherent": bool, "scattering": bool, "tx_pattern": str, "rx_pattern": str,
                  "rr_depth": int, "sampling": str, "diffraction": bool,
                  "min_rel_power": (int, float), "triangle_average": bool,
                  "facet_fresnel": (int, float), "max_facet_split": int, "reciprocal": bool}
DEFAULT_SOLVER = {"num_rays": 20000, "max_depth": 2}
DEFAULT_FRAMES_PER_SHARD = 50
_KEYS = {"scenes", "radars", "poses", "solver", "seed", "frames_per_shard"}


@dataclasses.dataclass
class DatasetSpec:
    """A validated spec (plain JSON-able values, absolute paths).

    Parameters
    ----------
    scenes : list
        list of scene entries (``name``, ``source`` or
        ``meshes``, ``materials``, ``allow_out_of_band``)
    radars : list
        list of ``{"name", "config"}``: ``RadarConfig.to_dict``
    poses : list
        list of pose dicts (:mod:`.poses`)
    solver : dict
        ``RadarPathSolver`` options
    seed : int
        base seed
    frames_per_shard : int
        frames per HDF5 shard
    path : str, optional
        the spec file (messages)
    """

    scenes: list
    radars: list
    poses: list
    solver: dict
    seed: int
    frames_per_shard: int
    path: str = "<spec>"

    @property
    def num_frames(self) -> int:
        return len(self.scenes) * len(self.radars) * len(self.poses)

    def as_dict(self) -> dict:
        """The spec content (without ``path``), as stored in the manifest."""
        return {k: getattr(self, k) for k in
                ("scenes", "radars", "poses", "solver", "seed", "frames_per_shard")}

    def digest(self) -> str:
        """sha256 of the spec content and the package version."""
        from .. import __version__

        text = json.dumps({"spec": self.as_dict(), "version": __version__}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()


def load_spec(path, frames_per_shard: int | None = None) -> DatasetSpec:
    """Read and validate a spec file; ``frames_per_shard`` overrides the spec's."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ConfigError(f"{path}: spec file does not exist")
    try:
        with open(path) as f:
            raw = json.load(f)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: not a JSON spec ({exc})") from None
    return parse_spec(raw, path, frames_per_shard)


def parse_spec(raw, path: str = "<spec>", frames_per_shard: int | None = None) -> DatasetSpec:
    """Validate a spec ``dict`` (paths relative to ``path``'s folder)."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: a spec is a JSON object, got {type(raw).__name__}")
    unknown = sorted(set(raw) - _KEYS)
    if unknown:
        raise ConfigError(f"{path}: unknown spec keys {unknown}; known {sorted(_KEYS)}")
    base = os.path.dirname(os.path.abspath(path)) if path != "<spec>" else os.getcwd()
    scenes = _names([_scene_entry(s, base, path) for s in _list(raw, "scenes", path)])
    radars = _names([_radar_entry(r, base, path) for r in _list(raw, "radars", path)])
    poses = poses_from_spec(raw.get("poses"), path)
    solver = _solver(raw.get("solver", DEFAULT_SOLVER), path)
    seed = raw.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{path}: seed must be an integer >= 0, got {seed!r}")
    fps = frames_per_shard if frames_per_shard is not None else raw.get(
        "frames_per_shard", DEFAULT_FRAMES_PER_SHARD)
    if isinstance(fps, bool) or not isinstance(fps, int) or fps < 1:
        raise ConfigError(f"{path}: frames_per_shard must be an integer >= 1, got {fps!r}")
    return DatasetSpec(scenes, radars, poses, solver, seed, fps, path)


def _list(raw, key, path) -> list:
    value = raw.get(key)
    if isinstance(value, (str, dict)):
        value = [value]
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{path}: '{key}' must be a non-empty list")
    return value


def _names(entries: list) -> list:
    seen: dict[str, int] = {}
    for e in entries:
        n = e["name"]
        if n in seen:
            seen[n] += 1
            e["name"] = f"{n}-{seen[n]}"
        else:
            seen[n] = 0
    return entries


def _file(value, base, path, what) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{path}: {what} must be a path string, got {value!r}")
    full = os.path.normpath(os.path.join(base, os.path.expanduser(value)))
    if not os.path.exists(full):
        raise ConfigError(f"{full}: {what} does not exist")
    return full


def _scene_entry(item, base, path) -> dict:
    if isinstance(item, str):
        item = {"source": item}
    if not isinstance(item, dict) or ("source" in item) == ("meshes" in item):
        raise ConfigError(f"{path}: a scene is a path, 'sionna:<name>', or an object with "
                          f"'source' or 'meshes', got {item!r}")
    extra = sorted(set(item) - {"name", "source", "meshes", "materials", "allow_out_of_band"})
    if extra:
        raise ConfigError(f"{path}: unknown scene keys {extra}")
    entry = {"materials": dict(item.get("materials") or {}),
             "allow_out_of_band": item.get("allow_out_of_band")}
    if "meshes" in item:
        meshes = item["meshes"]
        if not isinstance(meshes, dict) or not meshes:
            raise ConfigError(f"{path}: scene 'meshes' must be a non-empty object name -> path")
        entry["meshes"] = {k: _file(v, base, path, "mesh file") for k, v in meshes.items()}
        entry["name"] = str(item.get("name", "meshes"))
        return entry
    src = item["source"]
    if isinstance(src, str) and src.startswith("sionna:"):
        import sionna.rt.scene as built_in

        key = src.split(":", 1)[1]
        if not isinstance(getattr(built_in, key, None), str):
            raise ConfigError(f"{path}: {src!r} is not a Sionna built-in scene")
        entry["source"], entry["name"] = src, str(item.get("name", key))
        return entry
    entry["source"] = _file(src, base, path, "scene file")
    entry["name"] = str(item.get("name", os.path.splitext(os.path.basename(src))[0]))
    return entry


def _radar_entry(item, base, path) -> dict:
    from ..radar.config import RadarConfig

    if isinstance(item, str):
        is_dir = item not in RADAR_PRESETS and os.path.isdir(os.path.join(base, item))
        item = {"coloradar": item} if is_dir else {"preset": item}
    if not isinstance(item, dict) or ("preset" in item) == ("coloradar" in item):
        raise ConfigError(f"{path}: a radar is a preset name {list(RADAR_PRESETS)} or an object "
                          f"with 'preset' or 'coloradar', got {item!r}")
    extra = sorted(set(item) - {"name", "preset", "coloradar", "sensor", "chirps", "options"})
    if extra:
        raise ConfigError(f"{path}: unknown radar keys {extra}")
    chirps = item.get("chirps")
    if chirps is not None and (isinstance(chirps, bool) or not isinstance(chirps, int)
                               or chirps < 1):
        raise ConfigError(f"{path}: radar chirps must be an integer >= 1, got {chirps!r}")
    kw = {} if chirps is None else {"num_chirps": chirps}
    if "coloradar" in item:
        calib = _file(item["coloradar"], base, path, "ColoRadar calib folder")
        sensor = item.get("sensor", "cascade")
        from ..captures.coloradar_calib import read_coloradar_config

        radar = read_coloradar_config(calib, sensor=sensor, **kw)
        name = item.get("name", f"coloradar-{sensor}")
    else:
        preset = item["preset"]
        if preset not in RADAR_PRESETS:
            raise ConfigError(f"{path}: unknown radar preset {preset!r} (and no such "
                              f"ColoRadar calib folder); choose one of {list(RADAR_PRESETS)} "
                              "or a ColoRadar calib folder")
        options = dict(item.get("options") or {})
        try:
            radar = getattr(RadarConfig, preset)(**kw, **options)
        except TypeError as exc:
            raise ConfigError(f"{path}: radar {preset!r} options {options}: {exc}") from None
        name = item.get("name", preset)
    return {"name": str(name), "config": radar.to_dict()}


def _solver(solver, path) -> dict:
    if not isinstance(solver, dict):
        raise ConfigError(f"{path}: solver must be an object of RadarPathSolver options")
    out = dict(DEFAULT_SOLVER)
    for key, value in solver.items():
        kind = SOLVER_OPTIONS.get(key)
        if kind is None:
            raise ConfigError(f"{path}: unknown solver option {key!r}; known "
                              f"{sorted(SOLVER_OPTIONS)}")
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise ConfigError(f"{path}: solver.{key} has the wrong type: {value!r}")
        out[key] = value
    if out["num_rays"] < 1 or out["max_depth"] < 1:
        raise ConfigError(f"{path}: solver num_rays and max_depth must be >= 1")
    return out


def plan_frames(spec: DatasetSpec) -> list:
    """Manifest entries, one per frame (scene-major, then radar, then pose).

    Each entry: ``frame``, ``shard`` (file name), ``scene`` (scene entry),
    ``radar`` (``RadarConfig.to_dict`` posed at the frame), ``radar_name``,
    ``pose``, ``seed``, ``solver`` -- all :func:`~.render.render_frame` needs.
    """
    entries = []
    for scene in spec.scenes:
        for radar in spec.radars:
            for pose in spec.poses:
                i = len(entries)
                config = dict(radar["config"], position=pose["position"],
                              orientation=pose["orientation"])
                entries.append({"frame": i, "shard": shard_name(i // spec.frames_per_shard),
                                "scene": scene, "radar_name": radar["name"], "radar": config,
                                "pose": pose, "seed": spec.seed + i, "solver": spec.solver})
    return entries


def shard_name(index: int) -> str:
    """File name of shard ``index``."""
    return f"shard_{index:05d}.h5"
