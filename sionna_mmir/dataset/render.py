"""Render one dataset frame from its manifest entry (workers and verification alike)."""
from __future__ import annotations

import json
import warnings

import numpy as np

_SCENES: dict = {}
_CACHE_SIZE = 4


def load_entry_scene(scene: dict):
    """:class:`~sionna_mmir.scene.RadarScene` of a spec scene entry (cached per process).

    Out-of-band ITU materials are extrapolated as the spec entry's
    ``allow_out_of_band`` says, their warning shown once by the driver's
    validation, not by every worker.
    """
    from ..scene import load_scene
    from ..scene.sionna_import import OutOfBandMaterialWarning

    key = json.dumps(scene, sort_keys=True)
    if key not in _SCENES:
        if len(_SCENES) >= _CACHE_SIZE:
            _SCENES.pop(next(iter(_SCENES)))
        oob = scene.get("allow_out_of_band")
        mats = scene.get("materials") or None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfBandMaterialWarning)
            if "meshes" in scene:
                sc = load_scene(dict(scene["meshes"]), materials=mats, allow_out_of_band=oob)
            else:
                src = scene["source"]
                if src.startswith("sionna:"):
                    import sionna.rt.scene as built_in

                    src = getattr(built_in, src.split(":", 1)[1])
                sc = load_scene(src, materials=mats, allow_out_of_band=oob)
        _SCENES[key] = sc
    return _SCENES[key]


def render_frame(entry: dict) -> np.ndarray:
    """Raw ADC of one manifest entry, complex64 ``[tx, rx, chirp, sample]``.

    The result is a deterministic function of the entry: the same entry
    renders the same bits in any process and at any Dr.Jit thread count.

    Parameters
    ----------
    entry : dict
        a frame of ``manifest.json`` (:func:`~.spec.plan_frames`):
        ``scene``, ``radar`` (``RadarConfig.to_dict``, posed),
        ``pose`` (``velocity`` [m/s] -> Doppler), ``seed``, ``solver``
    """
    from ..paths import RadarPathSolver
    from ..paths.render import to_numpy
    from ..radar.config import RadarConfig

    scene = load_entry_scene(entry["scene"])
    radar = RadarConfig.from_dict(entry["radar"])
    scene.radar = radar                          # the scene holds the pose
    velocity = np.asarray(entry["pose"].get("velocity", (0.0, 0.0, 0.0)), dtype=np.float64)
    options = dict(entry["solver"])
    if np.any(velocity != 0):
        options["radar_velocity"] = tuple(float(v) for v in velocity)
    paths = _solver(RadarPathSolver)(scene, radar, seed=int(entry["seed"]), **options)
    return to_numpy(paths.adc(radar))


def _solver(cls, _cache={}):
    """One solver per process (it caches compiled kernels)."""
    if "solver" not in _cache:
        _cache["solver"] = cls()
    return _cache["solver"]
