"""The fit loop: min-max RA loss (paper eq. 7), Adam, progress bar, HDF5 checkpoints.

Each iteration renders with a fresh Monte Carlo sample set (seed ``seed +
iteration``), so the gradient is stochastic but the whole run is a
deterministic function of its settings.  A checkpoint holds the latents, the
Adam state and the loss history in float64; a fit killed at any point and
restarted with ``resume=True`` continues from the last checkpoint and reaches
the result of an uninterrupted run (to float32 rounding: Dr.Jit accumulates
gradients of gathers with multi-threaded atomics, so the summation order --
and the last bits -- can differ between any two runs).
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError, InputValueError
from ..utils.atomic import atomic_path
from .adam import Adam, schedule_lr

CHECKPOINT_FORMAT = "sionna_mmir.fit_checkpoint"


@dataclass
class FitResult:
    """Outcome of :func:`fit`.

    Parameters
    ----------
    latents : dict
        Name -> ``np.ndarray``: the final latents.
    history : numpy.ndarray
        ``[iterations]`` loss per iteration.
    seconds_per_it : float
        mean wall time of the iterations run here [s]
    iterations : int
        iterations completed (including resumed ones)
    resumed_from : int, optional
        iteration the run resumed from (0 = fresh)
    """

    latents: dict
    history: np.ndarray
    seconds_per_it: float
    iterations: int
    resumed_from: int = 0
    info: dict = field(default_factory=dict)


def _config(iterations, lr, schedule, seed, names_shapes, ra_kwargs):
    return json.dumps({"iterations": iterations, "lr": lr, "schedule": schedule, "seed": seed,
                       "params": names_shapes, "ra_kwargs": ra_kwargs}, sort_keys=True)


def save_checkpoint(path, z: dict, adam: Adam, history, config: str) -> None:
    """Atomic HDF5 checkpoint (see module docstring)."""
    import h5py

    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = CHECKPOINT_FORMAT
            f.attrs["config"] = config
            f.attrs["step"] = adam.step
            f.create_dataset("history", data=np.asarray(history, dtype=np.float64))
            for group, d in (("latents", z), ("adam_m", adam.m), ("adam_v", adam.v)):
                g = f.create_group(group)
                for k, v in d.items():
                    g.create_dataset(k, data=np.asarray(v, dtype=np.float64))


def load_checkpoint(path) -> dict:
    """Read a checkpoint -> ``{"latents", "m", "v", "step", "history", "config"}``."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != CHECKPOINT_FORMAT:
                raise InputValueError(f"{path}: not a sionna_mmir fit checkpoint")
            out = {"step": int(f.attrs["step"]), "config": str(f.attrs["config"]),
                   "history": f["history"][()]}
            for group, key in (("latents", "latents"), ("adam_m", "m"), ("adam_v", "v")):
                out[key] = {k: f[group][k][()] for k in f[group]}
            return out
    except OSError as exc:
        raise InputValueError(f"{path}: unreadable checkpoint ({exc})") from exc


def _target_map(target, radar, ra_kwargs):
    from ..processing.imaging import range_azimuth

    t = np.asarray(target)
    if np.iscomplexobj(t) and t.shape == tuple(radar.adc_shape):
        t = range_azimuth(t, radar, **ra_kwargs)[0]
    if t.ndim != 2 or np.iscomplexobj(t):
        raise InputValueError(f"fit: target must be a real RA map [range, azimuth] or complex "
                              f"ADC {tuple(radar.adc_shape)}, got {t.shape} {t.dtype}")
    if not np.isfinite(t).all():
        raise InputValueError("fit: target holds NaN or Inf")
    if t.max() - t.min() <= 0:
        raise InputValueError("fit: target RA map is constant (empty capture?)")
    return t


def fit(model, target, *, iterations: int = 100, lr: float = 0.05, schedule: str = "cosine",
        seed: int = 0, checkpoint: str | None = None, checkpoint_every: int = 10,
        resume: bool = True, progress: bool = True, ra_kwargs: dict | None = None,
        stop_after: int | None = None) -> FitResult:
    """Fit ``model`` to ``target`` by Adam on the min-max RA loss.

    Parameters
    ----------
    model : MMIRModel or SionnaModel
        :class:`~sionna_mmir.fit.models.MMIRModel` (or the
        Sionna baseline: anything with ``latents``,
        ``lr_scales``, ``render``, ``radar``)
    target : numpy.ndarray
        measured RA map ``[n_range, n_azimuth]`` or complex
        ADC ``radar.adc_shape``
    iterations : int, optional
        total Adam steps
    lr : float, optional
        base learning rate
    schedule : {"cosine", "exponential", "constant"}, optional
        learning-rate schedule (:func:`~sionna_mmir.fit.adam.schedule_lr`)
    seed : int, optional
        base seed; iteration ``i`` renders with ``seed + i``
    checkpoint : str, optional
        HDF5 path (written atomically every
        ``checkpoint_every`` iterations and at the end)
    checkpoint_every : int, optional
        iterations between checkpoints
    resume : bool, optional
        continue from ``checkpoint`` if it exists (its settings
        must match, else ``ConfigError``)
    progress : bool, optional
        tqdm progress bar with the loss
    ra_kwargs : dict, optional
        options of the range-azimuth processing
    stop_after : int, optional
        stop after this many iterations in *this* call (to
        simulate a killed run in tests)

    Returns
    -------
    FitResult
    """
    import drjit as dr
    from tqdm import tqdm

    from ..processing.drjit_ra import ra_loss_from_adc

    if int(iterations) < 1:
        raise ConfigError(f"fit: iterations must be >= 1, got {iterations}")
    if not np.isfinite(lr) or lr <= 0:
        raise ConfigError(f"fit: lr must be > 0, got {lr}")
    ra_kwargs = dict(ra_kwargs or {})
    radar = model.radar
    tmap = _target_map(target, radar, ra_kwargs)
    z = {k: np.asarray(v, dtype=np.float64) for k, v in model.latents().items()}
    scales = model.lr_scales()
    config = _config(int(iterations), float(lr), schedule, int(seed),
                     {k: list(v.shape) for k, v in z.items()}, ra_kwargs)
    adam = Adam()
    history: list[float] = []
    start = 0
    if checkpoint and resume and os.path.exists(checkpoint):
        ck = load_checkpoint(checkpoint)
        if ck["config"] != config:
            raise ConfigError(f"{checkpoint}: checkpoint was written by a fit with other "
                              "settings; remove it or pass resume=False")
        z = ck["latents"]
        adam.load_state({"m": ck["m"], "v": ck["v"], "step": ck["step"]})
        history = list(ck["history"])
        start = ck["step"]
    times = []
    bar = tqdm(range(start, int(iterations)), desc="fit", unit="it", disable=not progress,
               initial=start, total=int(iterations))
    done_here = 0
    for it in bar:
        t0 = time.perf_counter()
        adc, handles = model.render(z, seed=int(seed) + it)
        loss = ra_loss_from_adc(adc, radar, tmap, **ra_kwargs)
        dr.backward(loss)
        grads = {k: np.asarray(dr.grad(h), dtype=np.float64).reshape(z[k].shape)
                 for k, h in handles.items()}
        if hasattr(model, "pullback"):       # handles are not the latents (e.g. smoothed normals)
            grads = model.pullback(grads)
        value = float(np.asarray(dr.detach(loss))[0])
        if not np.isfinite(value):
            raise InputValueError(f"fit: loss became {value} at iteration {it}")
        z = adam.update(z, grads, schedule_lr(lr, it, int(iterations), schedule), scales)
        history.append(value)
        times.append(time.perf_counter() - t0)
        bar.set_postfix(loss=f"{value:.4g}")
        done_here += 1
        last = it + 1 == int(iterations)
        if checkpoint and ((it + 1) % max(int(checkpoint_every), 1) == 0 or last):
            save_checkpoint(checkpoint, z, adam, history, config)
        if stop_after is not None and done_here >= stop_after and not last:
            break
    bar.close()
    model.apply(z)
    return FitResult(latents=z, history=np.asarray(history), iterations=adam.step,
                     seconds_per_it=float(np.mean(times)) if times else float("nan"),
                     resumed_from=start)
