"""Run a dataset: validate, lock the output folder, write the manifest, render the
shards that are not finished (on Ray or in this process), finish the manifest.

Output folder::

    manifest.json      format, package / Sionna versions, spec and its digest,
                       seed, frames_per_shard, per shard its frames and sha256,
                       per frame its manifest entry (scene, posed radar, pose,
                       seed, solver, shard), complete
    shard_NNNNN.h5     frames (:mod:`.shards`)
    .lock              held (``flock``) while a job runs in the folder

Resuming: a run in a folder whose manifest has the same spec digest skips
every shard that :func:`~.shards.shard_is_complete` accepts and renders the
rest; temporary files of a killed run are removed.  A folder holding another
dataset needs ``overwrite=True``; one holding anything else is refused.

Parallelism: with Ray installed and ``workers != 1`` (or an ``address``),
each pending shard is one Ray task (1 CPU, Dr.Jit on ``threads`` threads)
returning its frames to this process, which writes the shards: the workers
need the scene files at the same paths, not a shared output folder.  Local
Ray (``address=None``) starts ``workers`` CPUs (0: all).  Without Ray the
shards render here, one after the other.
"""
from __future__ import annotations

import contextlib
import json
import os
import time

from ..errors import ConfigError
from ..utils.atomic import atomic_path
from . import shards as shard_io
from .render import load_entry_scene, render_frame
from .spec import DatasetSpec, load_spec, plan_frames

MANIFEST = "manifest.json"
LOCK = ".lock"
DATASET_FORMAT = "sionna_mmir.dataset"


def _import_ray():
    """The ``ray`` module, or None when it is not installed."""
    try:
        import ray
    except ImportError:
        return None
    return ray


@contextlib.contextmanager
def dataset_lock(out):
    """Hold ``<out>/.lock`` (``flock``, released when the process dies);
    ``ConfigError`` when another job holds it."""
    import fcntl

    os.makedirs(out, exist_ok=True)
    path = os.path.join(out, LOCK)
    with open(path, "a+") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.seek(0)
            owner = f.read().strip() or "?"
            raise ConfigError(f"{out}: locked by another running dataset job "
                              f"(pid {owner})") from None
        f.seek(0)
        f.truncate()
        f.write(str(os.getpid()))
        f.flush()
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def check_unlocked(out) -> None:
    """``ConfigError`` if a running job holds ``out``'s lock (writes nothing)."""
    import fcntl

    path = os.path.join(out, LOCK)
    if not os.path.isfile(path):
        return
    with open(path) as f:
        try:
            fcntl.flock(f, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            raise ConfigError(f"{out}: locked by another running dataset job "
                              f"(pid {f.read().strip() or '?'})") from None
        fcntl.flock(f, fcntl.LOCK_UN)


def _check_out(out, digest: str, overwrite: bool) -> None:
    """Refuse an output that is a file, holds another dataset (unless
    ``overwrite``) or holds anything but a dataset."""
    if not os.path.exists(out):
        return
    if not os.path.isdir(out):
        raise ConfigError(f"{out}: exists and is not a folder")
    check_unlocked(out)
    manifest = os.path.join(out, MANIFEST)
    if os.path.isfile(manifest):
        try:
            with open(manifest) as f:
                old = json.load(f)
        except (OSError, json.JSONDecodeError):
            old = {}
        if old.get("spec_digest") != digest and not overwrite:
            raise ConfigError(f"{out}: holds a dataset of another spec (or package version); "
                              "pass --overwrite to replace it or choose another folder")
        return
    others = [n for n in os.listdir(out) if n != LOCK and not n.startswith(".shard_")]
    if others:
        raise ConfigError(f"{out}: exists and is not a dataset folder ({len(others)} entries); "
                          "choose a new or empty folder")


def write_manifest(out, spec: DatasetSpec, entries: list, checksums: dict,
                   complete: bool) -> str:
    """Write ``<out>/manifest.json`` atomically (see module docstring)."""
    import sionna.rt

    from .. import __version__

    shards = {}
    for e in entries:
        shards.setdefault(e["shard"], []).append(e["frame"])
    doc = {"format": DATASET_FORMAT, "version": 1, "package_version": __version__,
           "sionna_rt_version": getattr(sionna.rt, "__version__", "?"),
           "spec_file": os.path.abspath(spec.path), "spec_digest": spec.digest(),
           "spec": spec.as_dict(), "seed": spec.seed, "num_frames": len(entries),
           "frames_per_shard": spec.frames_per_shard,
           "shards": [{"file": k, "frames": v, "sha256": checksums.get(k)}
                      for k, v in shards.items()],
           "frames": entries, "complete": bool(complete)}
    path = os.path.join(out, MANIFEST)
    with atomic_path(path) as tmp:
        with open(tmp, "w") as f:
            json.dump(doc, f, indent=1)
        shard_io.make_readable(tmp)
    return path


def read_manifest(out) -> dict:
    """``manifest.json`` of a dataset folder."""
    path = os.path.join(os.fspath(out), MANIFEST)
    if not os.path.isfile(path):
        raise ConfigError(f"{path}: no dataset manifest")
    with open(path) as f:
        return json.load(f)


def _by_shard(entries: list) -> dict:
    groups: dict = {}
    for e in entries:
        groups.setdefault(e["shard"], []).append(e)
    return groups


def _render_shard_task(entries: list, threads: int | None):
    """Body of a Ray task (also importable by workers): the shard's frames."""
    if threads:
        import drjit as dr

        dr.set_thread_count(int(threads))
    return [render_frame(e) for e in entries]


def run_dataset(spec, out, *, workers: int = 0, address: str | None = None,
                overwrite: bool = False, progress: bool = True, threads: int = 1,
                on_shard=None) -> dict:
    """Render a dataset into ``out`` (see module docstring).

    Parameters
    ----------
    spec : DatasetSpec or str or os.PathLike
        :class:`~.spec.DatasetSpec` or spec file path.
    out : str or os.PathLike
        Output folder.
    workers : int, optional
        parallel Ray tasks (0: all local CPUs); 1: this process
    address : str, optional
        Ray cluster address (``"auto"``, ``"ray://host:10001"``)
    overwrite : bool, optional
        replace a dataset of another spec (and re-render all)
    progress : bool, optional
        tqdm progress bar over frames
    threads : int, optional
        Dr.Jit threads per Ray task
    on_shard : callable, optional
        ``callable(shard_name)`` after each shard is written (a
        fault-injection hook for tests)

    Returns
    -------
    dict
        frames, shards, rendered / skipped shard names,
        mode (``"ray"`` | ``"local"`` | ``"local (ray not
        installed)"``), workers, seconds, frames_per_second
    """
    spec = spec if isinstance(spec, DatasetSpec) else load_spec(spec)
    out = os.fspath(out)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ConfigError(f"workers must be an integer >= 0, got {workers!r}")
    ray = _import_ray() if (workers != 1 or address) else None
    if address and ray is None:
        raise ConfigError(f"{address}: a Ray address needs Ray: pip install 'sionna_mmir[ray]'")
    mode = "ray" if ray is not None else (
        "local" if workers == 1 and not address else "local (ray not installed)")
    digest = spec.digest()
    entries = plan_frames(spec)
    _check_out(out, digest, overwrite)
    for scene in spec.scenes:                         # bad meshes fail here, before writing
        load_entry_scene(scene)
    with dataset_lock(out):
        if overwrite:
            _clear(out)
        shard_io.remove_partial_files(out)
        groups = _by_shard(entries)
        done = {k: v for k, v in groups.items()
                if shard_io.shard_is_complete(os.path.join(out, k), v, digest)}
        checksums = {k: _stored_checksum(os.path.join(out, k)) for k in done}
        write_manifest(out, spec, entries, checksums, complete=not (set(groups) - set(done)))
        pending = [(k, v) for k, v in groups.items() if k not in done]
        t0 = time.perf_counter()
        _execute(pending, out, digest, checksums, ray, workers, address, threads,
                 progress, on_shard, len(entries), sum(len(v) for v in done.values()))
        seconds = time.perf_counter() - t0
        write_manifest(out, spec, entries, checksums, complete=True)
    n_rendered = sum(len(v) for _, v in pending)
    return {"frames": len(entries), "shards": len(groups), "rendered": [k for k, _ in pending],
            "skipped": sorted(done), "mode": mode, "workers": workers, "seconds": seconds,
            "frames_per_second": n_rendered / seconds if n_rendered and seconds > 0 else None}


def _clear(out) -> None:
    for name in os.listdir(out):
        if name == MANIFEST or (name.startswith("shard_") and name.endswith(".h5")):
            os.remove(os.path.join(out, name))


def _stored_checksum(path) -> str:
    import h5py

    with h5py.File(path, "r") as f:
        return str(f.attrs["sha256"])


def _execute(pending, out, digest, checksums, ray, workers, address, threads, progress,
             on_shard, total, initial) -> None:
    from tqdm import tqdm

    def write(name, group, adcs):
        checksums[name] = shard_io.write_shard(os.path.join(out, name), group, adcs, digest)
        if on_shard is not None:
            on_shard(name)

    with tqdm(total=total, initial=initial, desc="dataset", unit="frame",
              disable=not progress) as bar:
        if ray is not None and pending:
            _execute_ray(pending, ray, workers, address, threads, write, bar)
            return
        for name, group in pending:
            adcs = []
            for e in group:
                adcs.append(render_frame(e))
                bar.update(1)
            write(name, group, adcs)


def _execute_ray(pending, ray, workers, address, threads, write, bar) -> None:
    started = not ray.is_initialized()
    if started:
        kw = {"address": address, "include_dashboard": False, "log_to_driver": False}
        if address is None:
            root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
            path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)
            kw.update(num_cpus=workers or os.cpu_count(),
                      runtime_env={"env_vars": {"PYTHONPATH": path}})
        ray.init(**kw)
    try:
        task = ray.remote(num_cpus=1)(_render_shard_task)
        limit = 2 * max(1, int(ray.cluster_resources().get("CPU", 1)))
        queue, running = list(pending), {}
        while queue or running:
            while queue and len(running) < limit:
                name, group = queue.pop(0)
                running[task.remote(group, threads)] = (name, group)
            ready, _ = ray.wait(list(running), num_returns=1)
            name, group = running.pop(ready[0])
            write(name, group, ray.get(ready[0]))
            bar.update(len(group))
    finally:
        if started:
            ray.shutdown()
