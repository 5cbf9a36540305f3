"""Adam (Kingma & Ba 2015) on NumPy arrays with checkpointable state.

The optimiser state is plain float64 arrays (``m``, ``v``, ``step``), so a fit
killed at any point resumes bit-for-bit from its HDF5 checkpoint.
"""
from __future__ import annotations

import math

import numpy as np


def schedule_lr(base: float, step: int, total: int, kind: str = "cosine",
                warmup: int = 0, final_ratio: float = 0.1) -> float:
    """Learning rate at ``step`` (0-based) of ``total``.

    ``kind``: ``"constant"``, ``"cosine"`` (to ``final_ratio * base``) or
    ``"exponential"`` (geometric decay to ``final_ratio * base``); optional
    linear ``warmup`` steps.
    """
    if warmup and step < warmup:
        return base * (step + 1) / warmup
    t = min(max(step - warmup, 0) / max(total - warmup - 1, 1), 1.0)
    if kind == "constant":
        return base
    if kind == "cosine":
        return base * (final_ratio + (1 - final_ratio) * 0.5 * (1 + math.cos(math.pi * t)))
    if kind == "exponential":
        return base * final_ratio ** t
    raise ValueError(f"unknown schedule {kind!r}")


class Adam:
    """Adam over a dict of named float64 arrays (per-group learning-rate scale)."""

    def __init__(self, beta1: float = 0.9, beta2: float = 0.999, eps: float = 1e-8):
        self.beta1, self.beta2, self.eps = beta1, beta2, eps
        self.m: dict[str, np.ndarray] = {}
        self.v: dict[str, np.ndarray] = {}
        self.step = 0

    def update(self, params: dict, grads: dict, lr: float, scales: dict | None = None) -> dict:
        """Return updated copies of ``params`` after one step."""
        self.step += 1
        b1, b2 = self.beta1, self.beta2
        out = {}
        for k, p in params.items():
            g = np.nan_to_num(np.asarray(grads.get(k, 0.0), dtype=np.float64))
            m = self.m.get(k, np.zeros_like(p))
            v = self.v.get(k, np.zeros_like(p))
            m = b1 * m + (1 - b1) * g
            v = b2 * v + (1 - b2) * g * g
            self.m[k], self.v[k] = m, v
            mh = m / (1 - b1 ** self.step)
            vh = v / (1 - b2 ** self.step)
            s = (scales or {}).get(k, 1.0)
            out[k] = p - lr * s * mh / (np.sqrt(vh) + self.eps)
        return out

    def state(self) -> dict:
        return {"m": self.m, "v": self.v, "step": self.step}

    def load_state(self, state: dict) -> None:
        self.m = {k: np.asarray(v, dtype=np.float64) for k, v in state["m"].items()}
        self.v = {k: np.asarray(v, dtype=np.float64) for k, v in state["v"].items()}
        self.step = int(state["step"])
