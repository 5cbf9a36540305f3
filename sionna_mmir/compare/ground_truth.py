"""Ground-truth captures of the benchmark scenes (:mod:`sionna_mmir.benchmark_scenes`).

Rendered with the mmIR path solver from the **clean** geometry (subdivided so
that materials vary), the **true** spatially varying per-vertex materials,
depth 3, free-space diffraction, ``frames`` independent sample sets (speckle
realisations, like frames of a static capture) and complex white receiver
noise ``noise_db`` below the peak ADC sample.  The fitter never sees any of
this except the capture.
"""
from __future__ import annotations

from ..benchmark_scenes.catalog import scene_radar  # noqa: F401  (re-export)

import numpy as np


def render_ground_truth(spec, *, seed: int = 0, num_rays: int = 100_000, max_depth: int = 3,
                        frames: int = 1, noise_db: float = -40.0, max_edge: float = 0.25,
                        sampling: str = "random", radar=None):
    """Return a :class:`~sionna_mmir.captures.Capture` of ``spec``'s ground truth.

    ``radar``: the posed radar to render (default :func:`scene_radar`, the
    cascade at the scene's pose).
    """
    import mitsuba as mi

    from ..captures.capture import Capture
    from ..paths import render, to_numpy
    from ..scene import load_scene
    from ..benchmark_scenes import true_materials

    radar = scene_radar(spec) if radar is None else radar
    clean = spec.refined(max_edge)
    scene = load_scene(clean, materials=spec.materials, radar=radar)
    truth = true_materials(spec, seed=seed, objects=clean)
    for name, obj in scene.mesh_objects.items():
        obj.vertex_materials = mi.TensorXf(truth[name].astype(np.float32))
    adc = np.stack([to_numpy(render(scene, num_rays=num_rays, max_depth=max_depth,
                                    diffraction=True, seed=1000 * seed + f, sampling=sampling))
                    for f in range(frames)])
    rng = np.random.default_rng(seed)
    sigma = np.abs(adc).max() * np.sqrt(10 ** (noise_db / 10) / 2)
    adc = adc + sigma * (rng.standard_normal(adc.shape) + 1j * rng.standard_normal(adc.shape))
    meta = {"scene": spec.description if hasattr(spec, "description") else "", "seed": seed,
            "num_rays": num_rays, "max_depth": max_depth, "diffraction": True,
            "noise_db": noise_db, "frames": frames, "sampling": sampling, "max_edge": max_edge}
    return Capture(adc.astype(np.complex64), radar, meta, "sionna_mmir.ground_truth")
