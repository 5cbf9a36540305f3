"""``Diagnosis(model).run()``: the residual loop on a :class:`~.radar_model.RadarModel`.

The one entry point for diagnosing a fitted model against its capture: it
renders the per-object basis if needed, refines the base (per-object gains,
pose) in the ADC domain, then adopts scene-side or sensor effects round by
round, refitting everything jointly after each adoption, until no candidate
predicts held-out channels better (:class:`~sionna_mmir.residual.diagnosis.DiagnosisRun`).
"""
from __future__ import annotations

from ..residual.diagnosis import DiagnosisRun
from ..residual.ranking import BIC


class Diagnosis:
    """The residual loop on a :class:`~.radar_model.RadarModel`.

    Parameters
    ----------
    model : RadarModel
        The fitted scene and its capture.
    candidates : list of Effect, optional
        Candidate effects (default :func:`~.loop.default_candidates`).
    folds, penalty, seed
        Cross-validation folds, nats per parameter (``"bic"``: ``ln(n) / 2``), fold seed.
    progress : callable, optional
        ``progress(event, name)`` (``"scored"`` / ``"adopted"`` / ``"vetoed"``).
    workers : int or "auto"
        Processes for the independent fits of a round (1: this process only).
    """

    def __init__(self, model, candidates=None, folds: int = 3, penalty=BIC,
                 seed: int = 0, progress=None, workers=1):
        from .loop import default_candidates

        self.model = model
        self.candidates = list(candidates) if candidates is not None else default_candidates()
        self.folds, self.penalty, self.seed, self.progress = folds, penalty, seed, progress
        self.workers = workers
        self.scene_mismatch = None

    def run(self):
        """Refine the base, then adopt until nothing helps; returns the result
        (:class:`~sionna_mmir.residual.diagnosis.Diagnosis`)."""
        if self.model.chain is None:
            self.model.attach()
        if not any(c.effect.scene_side for c in self.model.chain.components):
            self.scene_mismatch = self.model.refine()
        run = DiagnosisRun(self.model.chain, self.candidates, folds=self.folds,
                           penalty=self.penalty, seed=self.seed, progress=self.progress,
                           workers=self.workers)
        while not run.done:
            run.step()
        return run.result()
