"""sionna_mmir: differentiable mmWave FMCW radar rendering on top of Sionna RT.

Signal path and where each stage lives::

    radar/           RadarConfig: waveform, antenna layout, pose
    scene/           RadarScene (a sionna.rt.Scene), meshes, diffracting edges
    scaffold/        LiDAR mesh repair: denoising, plane snapping, shading
    radio_materials/ ITU-R P.2040 table, Fresnel / slab coefficients
    radio_devices/   learnable element beam patterns
    bsdf/            mmIR BSDF lobes (GGX, vMF, Lambertian) and FSD diffraction
    paths/           RadarPathSolver (a sionna.rt.PathSolver), SMS, render()
    fmcw/            per-path amplitudes + delays -> raw complex ADC
    processing/      range / Doppler / angle FFTs, virtual array, calibration
    captures/        Capture container, HDF5, TI .mat, ColoRadar, DCA1000 readers
    metrics/         the paper's Table 2 metrics on RA maps and ADC
    cli/             the ``sionna-mmir`` command line

Importing the package configures Dr.Jit's LLVM backend (see
:mod:`sionna_mmir.utils.backend`); Mitsuba itself is imported lazily, on the
first use of a Dr.Jit code path.
"""
from __future__ import annotations

import importlib

from .utils import backend as _backend

__version__ = "0.1.0"

if _backend.choose_variant().startswith("llvm"):
    _backend.configure_llvm()  # raises BackendError naming the fix

_LAZY = {
    "RadarConfig": ("sionna_mmir.radar.config", "RadarConfig"),
    "SPEED_OF_LIGHT": ("sionna_mmir.radar.config", "SPEED_OF_LIGHT"),
    "Capture": ("sionna_mmir.captures.capture", "Capture"),
    "load_capture": ("sionna_mmir.captures.loader", "load_capture"),
    "synthesize_adc": ("sionna_mmir.fmcw.synthesize", "synthesize_adc"),
    "range_azimuth": ("sionna_mmir.processing.imaging", "range_azimuth"),
    "range_azimuth_elevation": ("sionna_mmir.processing.imaging", "range_azimuth_elevation"),
    "metrics": ("sionna_mmir.metrics", None),
    "init_backend": ("sionna_mmir.utils.backend", "init_backend"),
    "load_scene": ("sionna_mmir.scene.load", "load_scene"),
    "RadarScene": ("sionna_mmir.scene.scene", "RadarScene"),
    "RadarPathSolver": ("sionna_mmir.paths.solver", "RadarPathSolver"),
    "RadarPaths": ("sionna_mmir.paths.radar_paths", "RadarPaths"),
    "render": ("sionna_mmir.paths.render", "render"),
    "render_capture": ("sionna_mmir.paths.render", "render_capture"),
    "SolverOptions": ("sionna_mmir.paths.options", "SolverOptions"),
    "ScaffoldOptions": ("sionna_mmir.scaffold.prepare", "ScaffoldOptions"),
}

__all__ = sorted(_LAZY)


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module 'sionna_mmir' has no attribute {name!r}")
    module, attr = _LAZY[name]
    mod = importlib.import_module(module)
    value = mod if attr is None else getattr(mod, attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(list(globals()) + list(_LAZY))
