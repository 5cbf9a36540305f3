"""``RadarModel``: scene -> solver -> ADC synthesis -> sensor chain, as one model.

The pieces the residual loop refits together:

1. **scene** -- a :class:`~sionna_mmir.scene.RadarScene` with per-vertex
   materials, normals and beam patterns, fitted to the capture's
   range-azimuth map (:class:`~sionna_mmir.fit.MMIRModel`, min-max RA loss);
2. **render** -- the fitted scene through the radar path solver (a
   deterministic facet quadrature by default), split per object into a
   :class:`~sionna_mmir.effects.scene_basis.SceneBasis`;
3. **chain** -- an :class:`~sionna_mmir.effects.EffectModel` on that basis:
   the scene-side effects (per-object gain, radar pose against the mesh
   frame, ...) and the adopted sensor effects, all fitted jointly by their
   likelihood in the complex ADC domain (right in range and phase, not only
   in RA magnitude).

:meth:`RadarModel.render` gives the model's ADC in the capture's units;
:meth:`RadarModel.state` / :meth:`RadarModel.restore` checkpoint it.
"""
from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..effects import EffectContext, EffectModel
from ..effects.library.scene_mismatch import BASE_REFINEMENT
from ..effects.scene_basis import SceneBasis, mesh_grounds, mesh_planes
from ..errors import InputValueError
from ..fit import MMIRModel
from ..paths.options import SolverOptions


def loop_solver_options(**changes) -> SolverOptions:
    """Solver settings of the residual loop: facet quadrature (deterministic,
    right on corner reflectors), depth 3, paths 60 dB down dropped."""
    return SolverOptions(**{"sampling": "facets", "max_depth": 3, "min_rel_power": 1e-6,
                            **changes})


@dataclasses.dataclass
class RadarModel:
    """A scene and a sensor chain fitted to one capture.

    Parameters
    ----------
    scene : RadarScene
        The scene (meshes in the radar's scene frame, the radar's pose).
    capture : Capture
        The measured capture (its radar is the model's radar).
    solver : SolverOptions
        Renders of the basis (default :func:`loop_solver_options`).
    learn : tuple of str
        What the RA fit learns (``MMIRModel`` learnables).
    max_objects : int
        Objects kept as components of their own in the basis.
    profile : SensorProfile, optional
        The unit's profile, applied frozen in the sensor chain (never fitted,
        never subtracted from the data).
    """

    scene: object
    capture: object
    solver: SolverOptions = dataclasses.field(default_factory=loop_solver_options)
    learn: tuple = ("materials", "beam")
    max_objects: int = 8
    profile: object = None
    mmir: object = None
    basis: SceneBasis = None
    chain: EffectModel = None
    latents: dict = None

    def __post_init__(self):
        self.scene.radar = self.radar                 # the scene holds the pose
        self.mmir = MMIRModel(self.scene, self.radar, learn=self.learn,
                              solver_options=self.solver)

    @property
    def radar(self):
        """The capture's radar (waveform, layout, pose)."""
        return self.capture.radar

    # --------------------------------------------------------------- stages
    def render_basis(self, seed: int = 0) -> SceneBasis:
        """Render the scene at the fitted latents and split it per object."""
        from ..paths import RadarPathSolver

        if self.latents is not None:
            self.mmir.apply(self.latents)
        paths = RadarPathSolver()(self.scene, self.radar, self.solver, seed=int(seed),
                                  tx_pattern=self.mmir.tx_pattern,
                                  rx_pattern=self.mmir.rx_pattern)
        if paths.num_paths == 0:
            raise InputValueError("the meshes and the capture do not overlap: no ray from the "
                                  "radar hits the meshes (meshes are expected in the radar's "
                                  "scene frame: +x boresight, +y left, +z up)")
        self.basis = SceneBasis.from_paths(paths, self.radar, max_objects=self.max_objects)
        self.basis.planes = mesh_planes(self.scene.mesh_objects, self.radar)
        self.basis.grounds = mesh_grounds(self.scene.mesh_objects, self.radar,
                                          self.basis.planes)
        return self.basis

    def attach(self) -> EffectModel:
        """The effects model on the basis (nuisance gain and floor fitted)."""
        if self.basis is None:
            self.render_basis()
        ctx = EffectContext.from_capture(self.capture, basis=self.basis)
        self.chain = EffectModel(ctx, self.capture.frames)
        if self.profile is not None:
            from ..effects.profile import frozen_profile_effect

            self.chain.add(frozen_profile_effect(self.profile, self.radar, self.chain.scale))
        self.chain.fit(trainable=[], maxiter=100)
        return self.chain

    def refine(self, maxiter: int = 200) -> dict:
        """Fit the base refinement (per-object gains, pose) in the ADC domain;
        returns what it absorbed (the scene mismatch)."""
        chain = self.chain or self.attach()
        work = chain.chirp_averaged()
        for cls in BASE_REFINEMENT:
            work.add(cls())
            work.fit(maxiter=maxiter)
        if work is not chain:
            chain.components = [copy.copy(c) for c in work.components]
            for c in chain.components:
                c.values = {k: np.array(v, copy=True) for k, v in c.values.items()}
            chain.nuisance.values["gain"] = np.array(work.nuisance.values["gain"], copy=True)
            chain.fit(trainable=[], maxiter=maxiter)
        return self.scene_mismatch()

    def scene_mismatch(self) -> dict:
        """Summaries of the fitted scene-side effects, by name."""
        if self.chain is None:
            return {}
        return {c.effect.name: c.effect.summary(c.values, self.chain.ctx)
                for c in self.chain.components if c.effect.scene_side}

    # ---------------------------------------------------------------- output
    def render(self) -> np.ndarray:
        """The model's ADC ``[F, T, R, C, N]`` in the capture's units."""
        if self.chain is None:
            raise InputValueError("RadarModel.render: attach() the capture first")
        return self.chain.mean_adc()

    def residual(self) -> np.ndarray:
        """Capture minus model, ``[F, T, R, C, N]``, capture units."""
        return self.chain.residual()

    def state(self) -> dict:
        """What a checkpoint holds to restore the model (latents, basis, chain)."""
        chain = None
        if self.chain is not None:
            chain = {"nuisance": {k: np.array(v) for k, v in self.chain.nuisance.values.items()},
                     "components": [(c.effect, {k: np.array(v) for k, v in c.values.items()},
                                     c.specs) for c in self.chain.components]}
        return {"latents": self.latents, "basis": self.basis, "chain": chain,
                "radar": self.radar.to_dict()}

    def restore(self, state: dict) -> None:
        """Inverse of :meth:`state`."""
        from ..effects.model import Component
        from ..radar.config import RadarConfig

        saved = state.get("radar")
        if saved is None or RadarConfig.from_dict(saved) != self.radar:
            raise InputValueError("the checkpoint was made for another radar than the "
                                  "capture's (resume with the capture it was started on)")
        self.latents = state["latents"]
        self.basis = state["basis"]
        if self.latents is not None:
            self.mmir.apply(self.latents)
        if state["chain"] is not None and self.basis is not None:
            ctx = EffectContext.from_capture(self.capture, basis=self.basis)
            self.chain = EffectModel(ctx, self.capture.frames)
            self.chain.nuisance.values = state["chain"]["nuisance"]
            self.chain.components = [Component(effect=e, specs=s, values=v)
                                     for e, v, s in state["chain"]["components"]]
