"""Occupancy metrics of a predicted point set against a reference set.

Nearest neighbours come from ``scipy.spatial.cKDTree``; with ``P`` the
predicted and ``Q`` the reference points, ``d_P(p) = min_q |p - q|`` and
``d_Q(q) = min_p |q - p|`` [m], and the match threshold ``tau`` (0.5 m):

=============  =============================================================
precision      ``|{p : d_P(p) <= tau}| / |P|``
recall         ``|{q : d_Q(q) <= tau}| / |Q|``
f1             ``2 precision recall / (precision + recall)`` (0 if both 0)
accuracy       ``(|{p : d_P <= tau}| + |{q : d_Q <= tau}|) / (|P| + |Q|)``,
               the matched fraction of all points of both sets
rmse           ``sqrt((sum_p d_P^2 + sum_q d_Q^2) / (|P| + |Q|))`` [m], over
               both sets, no threshold
chamfer        ``(mean_p d_P + mean_q d_Q) / 2`` [m]
r_cd           ``chamfer / scale``; ``scale`` defaults to the diagonal of the
               reference set's axis-aligned bounding box (the scene extent)
=============  =============================================================

Accuracy: the paper does not define it.  In its Table 4 accuracy always lies
between recall and precision and exceeds F1 in four of seven rows, which
rules out the Jaccard index ``TP / (TP + FP + FN)`` (never above F1); the
pooled matched fraction above fits every row.  RMSE and the Chamfer distance
pool both directions for the same reason (a precision of 0.997 with an RMSE
of 0.91 m cannot come from the predicted-to-reference distances alone).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputValueError

#: Default match threshold [m] (the paper's tau).
DEFAULT_TAU = 0.5

#: Metric keys in table order.
METRIC_KEYS = ("precision", "recall", "f1", "accuracy", "rmse", "chamfer", "r_cd")


def _points(x, what):
    p = np.asarray(x, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputValueError(f"occupancy_metrics: {what} points must be [n, 3], got {p.shape}")
    if len(p) == 0:
        raise InputValueError(f"occupancy_metrics: empty point cloud ({what} set has no points)")
    if not np.isfinite(p).all():
        raise InputValueError(f"occupancy_metrics: {what} points hold NaN or Inf")
    return p


def nearest_distances(points, to) -> np.ndarray:
    """Nearest-neighbour distances (``scipy.spatial.cKDTree``).

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Query points [m].
    to : array_like, shape (m, 3)
        Points searched [m].

    Returns
    -------
    ndarray of float64, shape (n,)
        Distance of each query point to its nearest neighbour in ``to`` [m].
    """
    d, _ = cKDTree(np.asarray(to, float)).query(np.asarray(points, float), k=1)
    return np.asarray(d, dtype=np.float64)


def occupancy_metrics(predicted, reference, tau: float = DEFAULT_TAU,
                      scale: float | None = None) -> dict:
    """Precision, recall, F1, accuracy, RMSE, Chamfer and relative Chamfer distance.

    Parameters
    ----------
    predicted : array_like, shape (n, 3)
        Predicted points [m].
    reference : array_like, shape (m, 3)
        Reference points [m].
    tau : float, optional
        Match threshold [m] (0.5).
    scale : float, optional
        R-CD normaliser [m]; default the reference bounding-box diagonal.

    Returns
    -------
    dict
        :data:`METRIC_KEYS` (``rmse`` and ``chamfer`` in m) plus
        ``n_predicted``, ``n_reference``, ``tau`` and ``scale`` (module
        docstring).

    Raises
    ------
    InputValueError
        An empty point set, a wrong shape, NaN / Inf, or ``tau <= 0``.
    """
    p, q = _points(predicted, "predicted"), _points(reference, "reference")
    if not (np.isfinite(tau) and tau > 0):
        raise InputValueError(f"occupancy_metrics: tau must be positive, got {tau!r}")
    d_p, d_q = nearest_distances(p, q), nearest_distances(q, p)
    hit_p, hit_q = int(np.count_nonzero(d_p <= tau)), int(np.count_nonzero(d_q <= tau))
    precision, recall = hit_p / len(p), hit_q / len(q)
    f1 = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    if scale is None:
        scale = float(np.linalg.norm(q.max(axis=0) - q.min(axis=0)))
    chamfer = 0.5 * (d_p.mean() + d_q.mean())
    return {"precision": precision, "recall": recall, "f1": f1,
            "accuracy": (hit_p + hit_q) / (len(p) + len(q)),
            "rmse": float(np.sqrt((np.sum(d_p ** 2) + np.sum(d_q ** 2)) / (len(p) + len(q)))),
            "chamfer": float(chamfer),
            "r_cd": float(chamfer / scale) if scale > 0 else float("nan"),
            "n_predicted": len(p), "n_reference": len(q), "tau": float(tau),
            "scale": float(scale)}
