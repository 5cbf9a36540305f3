"""``render``: scene + radar -> raw FMCW ADC, one Dr.Jit graph.

    rays -> interactions (AD) -> BSDF / physical optics -> per-pair phasors
    (:class:`~sionna_mmir.paths.solver.RadarPathSolver`) -> ADC
    (:func:`~sionna_mmir.fmcw.synthesize_adc`)

:func:`render_capture` renders several frames (a new seed each) into a
:class:`~sionna_mmir.captures.Capture`, optionally with receiver noise.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError, InputValueError
from .options import SolverOptions
from .solver import RadarPathSolver, radar_of


def render(scene, radar=None, options: SolverOptions | dict | None = None, *,
           solver: RadarPathSolver | None = None, return_paths: bool = False, **overrides):
    """Render one frame of raw ADC ``[tx, rx, chirp, sample]``.

    Parameters
    ----------
    scene : RadarScene
        The scene (its pose tensors place the radar).
    radar : RadarConfig, optional
        Waveform and layout (default ``scene.radar``).
    options : SolverOptions or dict, optional
        Solver settings (default ``SolverOptions()``); keyword ``overrides``
        replace its fields (``num_rays``, ``max_depth``, ``seed``, ...).
    solver : RadarPathSolver, optional
        A solver to reuse (default: a new one).
    return_paths : bool
        Also return the :class:`RadarPaths`.

    Returns
    -------
    DrAdc or tuple
        ``DrAdc`` (``real``, ``imag`` ``mi.TensorXf``) inside the AD graph;
        ``(adc, paths)`` with ``return_paths``.  :func:`to_numpy` converts it
        to complex64.
    """
    radar = radar_of(scene, radar)
    paths = (solver or RadarPathSolver())(scene, radar, options, **overrides)
    adc = paths.adc(radar)
    return (adc, paths) if return_paths else adc


def to_numpy(adc) -> np.ndarray:
    """``DrAdc`` -> complex64 ``np.ndarray`` (detached)."""
    import drjit as dr

    re = np.asarray(dr.detach(adc.real), dtype=np.float32)
    im = np.asarray(dr.detach(adc.imag), dtype=np.float32)
    return (re + 1j * im).astype(np.complex64)


def render_capture(scene, radar=None, options: SolverOptions | None = None, *, frames: int = 1,
                   noise_db: float | None = None, metadata: dict | None = None,
                   progress: bool = False):
    """Render ``frames`` frames (seed ``options.seed + f``) into a Capture.

    Parameters
    ----------
    scene : RadarScene
        The scene.
    radar : RadarConfig, optional
        Waveform and layout (default ``scene.radar``).
    options : SolverOptions, optional
        Solver settings (default ``SolverOptions()``).
    frames : int
        Number of frames, each with its own sample set.
    noise_db : float, optional
        Complex white receiver noise power per ADC sample relative to the
        peak sample's power [dB] (none when ``None``).
    metadata : dict, optional
        Stored with the capture (the solver settings and ray hits are added).
    progress : bool
        Show a progress bar over frames.

    Returns
    -------
    Capture
        ``frames [F, tx, rx, chirp, sample]`` complex64.
    """
    from tqdm import tqdm

    from ..captures.capture import Capture

    radar = radar_of(scene, radar)
    options = options or SolverOptions()
    if int(frames) < 1:
        raise ConfigError(f"frames must be >= 1, got {frames}")
    if noise_db is not None and not (np.isfinite(noise_db) and abs(float(noise_db)) <= 300):
        raise ConfigError(f"noise_db {noise_db}: expected a finite number of dB within +-300")
    solver, out, hits = RadarPathSolver(), [], []
    for f in tqdm(range(int(frames)), desc="render", unit="frame", disable=not progress):
        paths = solver(scene, radar, options, seed=int(options.seed) + f)
        if paths.num_paths == 0:
            raise InputValueError("no ray from the radar hits the meshes: check the radar pose "
                                  "and that the meshes lie in front of the radar (meshes are "
                                  "expected in the radar's scene frame: +x boresight, +y left, "
                                  "+z up)")
        hits.append(int(paths.info["hits"]))
        out.append(to_numpy(paths.adc(radar)))
    adc = np.stack(out)
    if noise_db is not None:
        rng = np.random.default_rng(int(options.seed))
        peak = float(np.abs(adc).max()) or 1.0
        sigma = peak * np.sqrt(10 ** (float(noise_db) / 10) / 2)
        adc = adc + (sigma * (rng.standard_normal(adc.shape)
                              + 1j * rng.standard_normal(adc.shape))).astype(np.complex64)
    meta = dict(metadata or {})
    meta.update({"solver": options.describe(), "noise_db": noise_db, "hits": hits})
    return Capture(adc.astype(np.complex64), radar, meta, "sionna_mmir.render")
