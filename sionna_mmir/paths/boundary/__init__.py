"""Boundary (visibility) term of the radar path solver's geometry and pose gradients.

================  ============================================================
``silhouette``    silhouette edges seen from the array and stratified samples
                  on them
``estimator``     the edge-sampling boundary term as zero-valued paths whose
                  derivative is the visibility change (Li et al. 2018;
                  Zhang et al. 2023)
================  ============================================================

Switched by :attr:`SolverOptions.boundary <sionna_mmir.paths.SolverOptions>`.
"""
from .estimator import boundary_emissions
from .silhouette import EdgeSamples, SilhouetteEdges

__all__ = ["boundary_emissions", "EdgeSamples", "SilhouetteEdges"]
