"""Fittable models: the mmIR radar model on a :class:`~sionna_mmir.scene.RadarScene`.

A *model* exposes

===================  =====================================================
``latents()``        ``dict name -> np.ndarray`` (float64) initial latents
``lr_scales()``      ``dict name -> float`` learning-rate multipliers
``render(z, seed)``  ``(adc, handles)``: a ``DrAdc`` rendered from latents
                     ``z`` (``dict name -> np.ndarray``) inside the AD graph,
                     and the grad-enabled Dr.Jit arrays keyed like ``z``
``apply(z)``         write latents into the scene (no gradients)
===================  =====================================================

so that :func:`~sionna_mmir.fit.fitter.fit` can optimise it; the Sionna RT
baseline (:mod:`sionna_mmir.baseline`) implements the same interface.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from . import reparam

#: what :class:`MMIRModel` can learn
LEARNABLE = ("materials", "normals", "beam", "positions", "pose")


class MMIRModel:
    """mmIR model: per-vertex materials, normals, beam patterns (+ positions, pose).

    ================  ========================================================
    scene             :class:`~sionna_mmir.scene.RadarScene`
    radar             :class:`~sionna_mmir.radar.RadarConfig` (default
                      ``scene.radar``)
    learn             subset of ``("materials", "normals", "beam",
                      "positions", "pose")`` (paper default: the first three)
    tx_pattern,       element patterns; default one learnable
    rx_pattern        :class:`~sionna_mmir.radio_devices.CosinePowerPattern`
                      per element
    solver_options    options of :class:`~sionna_mmir.paths.RadarPathSolver`
                      (``num_rays``, ``max_depth``, ``cone_angle_deg``, ...)
    min_rel_power     paths weaker than this x the strongest are left out of
                      the ADC synthesis (default 1e-8, -80 dB: on the
                      facet-sampled hallway at depth 3 it drops half of 2M
                      paths holding 1.2e-5 of the power; 0 keeps all)
    ================  ========================================================
    """

    def __init__(self, scene, radar=None, *, learn=("materials", "normals", "beam"),
                 tx_pattern=None, rx_pattern=None, solver_options: dict | None = None,
                 min_rel_power: float = 1e-8):
        from ..paths import RadarPathSolver
        from ..radio_devices import CosinePowerPattern

        self.scene = scene
        self.radar = radar if radar is not None else scene.radar
        if self.radar is None:
            raise ConfigError("MMIRModel: no radar (give radar= or load_scene(..., radar=))")
        bad = sorted(set(learn) - set(LEARNABLE))
        if bad:
            raise ConfigError(f"MMIRModel: cannot learn {bad}; choose from {LEARNABLE}")
        self.learn = tuple(learn)
        self.tx_pattern = tx_pattern or CosinePowerPattern(n_elements=self.radar.num_tx)
        self.rx_pattern = rx_pattern or CosinePowerPattern(n_elements=self.radar.num_rx)
        if not (np.isfinite(min_rel_power) and 0 <= min_rel_power < 1):
            raise ConfigError(f"MMIRModel: min_rel_power must be in [0, 1), got {min_rel_power!r}")
        self.min_rel_power = float(min_rel_power)
        self.solver = RadarPathSolver()
        self.options = dict(num_rays=20_000, max_depth=2)
        self.options.update(solver_options or {})

    # ---------------------------------------------------------------- latents
    def latents(self) -> dict:
        z = {}
        for name, obj in self.scene.mesh_objects.items():
            if "materials" in self.learn:
                z[f"{name}.materials"] = reparam.to_latent(np.array(obj.vertex_materials))
            if "normals" in self.learn:
                z[f"{name}.normals"] = np.array(obj.vertex_normals, dtype=np.float64)
            if "positions" in self.learn:
                z[f"{name}.positions"] = np.array(obj.vertex_positions, dtype=np.float64)
        if "beam" in self.learn:
            for side, pat in (("tx", self.tx_pattern), ("rx", self.rx_pattern)):
                for key, val in pat.params().items():
                    z[f"beam.{side}.{key}"] = np.array(val, dtype=np.float64)
        if "pose" in self.learn:
            z["pose.position"] = np.array(self.scene.position, dtype=np.float64)
            z["pose.orientation"] = np.array(self.scene.orientation, dtype=np.float64)
        return z

    def lr_scales(self) -> dict:
        """Per-group LR multipliers (positions / pose move in metres / radians).

        Normals take a tenth of the materials' step: at the full step they
        chase the min-max loss's few peaks and the rest of the map degrades
        (hallway, facet quadrature, 8 iterations at lr 0.05: materials alone
        0.42 -> 0.58, + normals and beams at 0.1x 0.42 -> 0.69; at 1x on a
        150k mesh 0.64 -> 0.44). On a *denoised* scaffold (normals within
        ~0.1 deg already) even this step costs accuracy (lab, 12 iterations:
        0.821 with normals vs 0.855 without); leave them out of ``learn``
        there (NOTES.md, session 6).
        """
        out = {}
        for k in self.latents():
            out[k] = {"positions": 0.01, "position": 0.01, "orientation": 0.01,
                      "normals": 0.1}.get(k.rsplit(".", 1)[-1], 1.0)
        return out

    # ----------------------------------------------------------------- render
    def _assign(self, z: dict, grad: bool) -> dict:
        import drjit as dr
        import mitsuba as mi

        handles = {}

        def var(key, arr):
            a = np.ascontiguousarray(arr, dtype=np.float32)
            t = mi.TensorXf(mi.Float(a.ravel()), a.shape) if a.ndim > 1 else mi.Float(a)
            if grad:
                dr.enable_grad(t)
            handles[key] = t
            return t

        for name, obj in self.scene.mesh_objects.items():
            k = f"{name}.materials"
            if k in z:
                t = var(k, z[k])
                n = z[k].shape[0]
                obj.vertex_materials = mi.TensorXf(reparam.to_physical_dr(t.array, n), (n, 6))
            k = f"{name}.normals"
            if k in z:
                obj.vertex_normals = var(k, z[k])
            k = f"{name}.positions"
            if k in z:
                obj.vertex_positions = var(k, z[k])
        for side, pat in (("tx", self.tx_pattern), ("rx", self.rx_pattern)):
            vals = {key: var(f"beam.{side}.{key}", z[f"beam.{side}.{key}"])
                    for key in pat.params() if f"beam.{side}.{key}" in z}
            for key, t in vals.items():
                setattr(pat, key, t)
        if "pose.position" in z:
            self.scene.position = mi.TensorXf(var("pose.position", z["pose.position"]), (3,))
            self.scene.orientation = mi.TensorXf(var("pose.orientation", z["pose.orientation"]), (3,))
        if any(k.endswith(".positions") for k in z):
            self.scene.sync()
        return handles

    def apply(self, z: dict) -> None:
        """Write latents into the scene (detached)."""
        self._assign(z, grad=False)

    def render(self, z: dict, seed: int):
        """``(DrAdc, handles)`` for latents ``z`` with a fresh sample set ``seed``."""
        handles = self._assign(z, grad=True)
        paths = self.solver(self.scene, self.radar, seed=int(seed), tx_pattern=self.tx_pattern,
                            rx_pattern=self.rx_pattern, **self.options)
        return paths.adc(self.radar, self.min_rel_power), handles

    def physical(self, z: dict) -> dict:
        """Latents -> physical values (materials through the reparameterisation)."""
        out = {}
        for k, v in z.items():
            out[k] = reparam.to_physical(v) if k.endswith(".materials") else np.asarray(v)
        return out


class SionnaModel:
    """The Sionna RT baseline (:class:`~sionna_mmir.baseline.SionnaBaseline`) as a model.

    Learns what Sionna exposes: per-object material scalars (relative
    permittivity, conductivity, scattering / XPD coefficients, thickness), as
    the baseline's latents; same loss, optimiser and iteration budget as
    :class:`MMIRModel`.
    """

    def __init__(self, baseline):
        self.baseline = baseline
        self.radar = baseline.radar

    def latents(self) -> dict:
        import drjit as dr

        return {k: np.asarray(dr.detach(v), dtype=np.float64).reshape(-1)
                for k, v in self.baseline.params().items()}

    def lr_scales(self) -> dict:
        return {k: 1.0 for k in self.latents()}

    def _vars(self, z, grad):
        import drjit as dr
        import mitsuba as mi

        out = {}
        for k, v in z.items():
            t = mi.Float(np.asarray(v, dtype=np.float32).reshape(-1))
            if grad:
                dr.enable_grad(t)
            out[k] = t
        return out

    def apply(self, z: dict) -> None:
        self.baseline.apply(self._vars(z, grad=False))

    def render(self, z: dict, seed: int):
        handles = self._vars(z, grad=True)
        self.baseline.apply(handles)
        return self.baseline.render(seed=int(seed)), handles
