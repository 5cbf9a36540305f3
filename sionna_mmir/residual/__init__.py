"""Close the loop with measured data: residual analysis, diagnosis and report.

``analysis`` (the residual in every domain), ``scoring`` (metrics of a model
against a capture), ``diagnosis`` (cross-validated ranking and adoption of
effects), ``report`` (JSON / Markdown / PNG).
"""
from .analysis import residual_domains
from .diagnosis import Diagnosis, diagnose
from .ranking import cv_folds, rank_candidates

__all__ = ["residual_domains", "Diagnosis", "cv_folds", "diagnose", "rank_candidates"]
