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
#: the radar pose's degrees of freedom (position, then yaw, pitch, roll)
POSE_DOFS = ("x", "y", "z", "yaw", "pitch", "roll")


class MMIRModel:
    """mmIR model: per-vertex materials, normals, beam patterns (+ positions, pose).

    Parameters
    ----------
    scene : RadarScene
        The scene (:class:`~sionna_mmir.scene.RadarScene`).
    radar : RadarConfig, optional
        :class:`~sionna_mmir.radar.RadarConfig` (default
        ``scene.radar``)
    learn : tuple, optional
        subset of ``("materials", "normals", "beam",
        "positions", "pose")`` (paper default: the first three)
    tx_pattern, rx_pattern : BeamPattern, optional
        element patterns; default one learnable
        :class:`~sionna_mmir.radio_devices.CosinePowerPattern`
        per element
    solver_options : SolverOptions or dict, optional
        :class:`~sionna_mmir.paths.SolverOptions` of every
        render (a dict changes fields of the default); default
        :meth:`SolverOptions.fit` (depth 2, paths 60 dB
        under the strongest dropped before their
        per-element legs: invisible in a min-max RA loss)
    normals_smoothing : float, optional
        ``lambda`` of the Laplacian ("large steps")
        parameterisation of the learned normals
        (:mod:`~sionna_mmir.fit.smooth_param`; Nicolet et al.
        2021): the latents are ``(I + lambda L) n`` per object,
        so per-vertex noise in the steps is averaged over
        ``~sqrt(lambda)`` edges while a whole surface can still
        tilt (default 0: raw per-vertex normals)
    materials_smoothing : float, optional
        the same for the materials' latents (a spatial
        smoothness prior on the six per-vertex parameters;
        default 0)
    pose_dofs : tuple, optional
        with ``"pose"`` learned: which of ``("x", "y", "z",
        "yaw", "pitch", "roll")`` move (default all).  A
        range-azimuth map sees range and azimuth only, so
        height, pitch and roll are barely observable from it;
        an alignment fit to RA maps learns ``("x", "y",
        "yaw")`` and keeps the others at their values
    materials_per : {"vertex", "object"}, optional
        ``"vertex"`` (default): six parameters per vertex;
        ``"object"``: six per object, shared by all its vertices
        (the latent is ``[1, 6]``, initialised with the mean
        of the vertices' latents)
    """

    def __init__(self, scene, radar=None, *, learn=("materials", "normals", "beam"),
                 tx_pattern=None, rx_pattern=None, solver_options=None,
                 normals_smoothing: float = 0.0, materials_smoothing: float = 0.0,
                 pose_dofs: tuple = POSE_DOFS, materials_per: str = "vertex"):
        from ..paths import RadarPathSolver, SolverOptions
        from ..radio_devices import CosinePowerPattern

        self.scene = scene
        self.radar = radar if radar is not None else scene.radar
        if self.radar is None:
            raise ConfigError("MMIRModel: no radar (give radar= or load_scene(..., radar=))")
        bad = sorted(set(learn) - set(LEARNABLE))
        if bad:
            raise ConfigError(f"MMIRModel: cannot learn {bad}; choose from {LEARNABLE}")
        self.learn = tuple(learn)
        bad = sorted(set(pose_dofs) - set(POSE_DOFS))
        if bad or not pose_dofs:
            raise ConfigError(f"MMIRModel: pose_dofs must be a non-empty subset of {POSE_DOFS}, "
                              f"got {tuple(pose_dofs)}")
        #: 1 for the pose components that move (position, orientation)
        self._pose_mask = np.array([d in pose_dofs for d in POSE_DOFS], dtype=np.float64)
        if materials_per not in ("vertex", "object"):
            raise ConfigError(f"MMIRModel: materials_per must be 'vertex' or 'object', "
                              f"got {materials_per!r}")
        if materials_per == "object" and materials_smoothing > 0:
            raise ConfigError("MMIRModel: materials_smoothing needs per-vertex materials")
        self.materials_per = materials_per
        self.tx_pattern = tx_pattern or CosinePowerPattern(n_elements=self.radar.num_tx)
        self.rx_pattern = rx_pattern or CosinePowerPattern(n_elements=self.radar.num_rx)
        #: latent key -> LaplacianParam (handles are the smoothed fields, see pullback)
        self._smooth = {}
        for what, lam in (("normals", normals_smoothing), ("materials", materials_smoothing)):
            if not (np.isfinite(lam) and lam >= 0):
                raise ConfigError(f"MMIRModel: {what}_smoothing must be >= 0, got {lam!r}")
            setattr(self, f"{what}_smoothing", float(lam))
            if what in self.learn and lam > 0:
                from .smooth_param import LaplacianParam

                for name, obj in scene.mesh_objects.items():
                    self._smooth[f"{name}.{what}"] = LaplacianParam(
                        obj.faces, obj.vertex_positions.shape[0], float(lam))
        self.solver = RadarPathSolver()
        if isinstance(solver_options, dict):          # fields changed from the fit preset
            self.options = SolverOptions.fit().replace(**solver_options)
        else:
            self.options = SolverOptions.resolve(solver_options or SolverOptions.fit())

    # ---------------------------------------------------------------- latents
    def latents(self) -> dict:
        z = {}
        for name, obj in self.scene.mesh_objects.items():
            if "materials" in self.learn:
                zm = reparam.to_latent(np.array(obj.vertex_materials))
                if self.materials_per == "object":
                    zm = zm.mean(axis=0, keepdims=True)
                z[f"{name}.materials"] = zm
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
        for k, par in self._smooth.items():
            z[k] = par.to_latent(z[k])
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
        there.
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
            if key in self._smooth:       # the handle is the smoothed field; pullback() maps its grad
                arr = self._smooth[key].from_latent(arr)
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
                n = obj.vertex_positions.shape[0]
                flat = t.array
                if z[k].shape[0] != n:        # per-object latent [1, 6]: every vertex shares it
                    flat = dr.gather(mi.Float, flat, dr.arange(mi.UInt32, n * 6) % 6)
                obj.vertex_materials = mi.TensorXf(reparam.to_physical_dr(flat, n), (n, 6))
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

    def pullback(self, grads: dict) -> dict:
        """Gradients w.r.t. the render handles -> gradients w.r.t. the latents
        (identity except for Laplacian-parameterised normals or materials:
        ``A^-1 g``, and pose components outside ``pose_dofs``: zero)."""
        out = dict(grads)
        for k, par in self._smooth.items():
            if k in out:
                out[k] = par.pullback(out[k])
        if "pose.position" in out:           # components held fixed get no step
            out["pose.position"] = out["pose.position"] * self._pose_mask[:3]
            out["pose.orientation"] = out["pose.orientation"] * self._pose_mask[3:]
        return out

    def apply(self, z: dict) -> None:
        """Write latents into the scene (detached)."""
        self._assign(z, grad=False)

    def render(self, z: dict, seed: int):
        """``(DrAdc, handles)`` for latents ``z`` with a fresh sample set ``seed``."""
        handles = self._assign(z, grad=True)
        # paths are pruned inside the solver, before their per-element legs
        paths = self.solver(self.scene, self.radar, self.options, seed=int(seed),
                            tx_pattern=self.tx_pattern, rx_pattern=self.rx_pattern)
        return paths.adc(self.radar), handles

    def physical(self, z: dict) -> dict:
        """Latents -> physical values (materials through the reparameterisation,
        normals as unit vectors, through the Laplacian parameterisation if set)."""
        out = {}
        for k, v in z.items():
            v = self._smooth[k].from_latent(v) if k in self._smooth else np.asarray(v)
            out[k] = reparam.to_physical(v) if k.endswith(".materials") else v
            if k.endswith(".normals"):        # unit shading normals, as the renderer uses them
                out[k] = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
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
