"""Sharded HDF5 output: atomic shard writes, completion marker, checksums.

A shard ``shard_NNNNN.h5`` holds consecutive frames::

    /                      attrs: format, version, dataset (spec digest),
                                  frames (JSON list of frame indices),
                                  sha256 (of the frames' ADC bytes, in order),
                                  complete (True; written last)
    /frames/<frame:07d>/adc      complex64 [tx, rx, chirp, sample]
    /frames/<frame:07d>          attrs: radar (RadarConfig JSON, posed),
                                  pose (JSON), seed, scene (JSON)

It is written to a temporary file beside it and renamed when complete, so a
killed writer leaves no shard (only a ``.shard_*.part`` file, removed by the
next run).  :func:`shard_is_complete` accepts a shard only when its marker,
its dataset digest and frame list match and the checksum of its data agrees.
"""
from __future__ import annotations

import glob
import hashlib
import json
import os

import numpy as np

from ..utils.atomic import atomic_path

SHARD_FORMAT = "sionna_mmir.dataset_shard"


def make_readable(path) -> None:
    """Give a temporary file (created 0600) the usual ``0666 & ~umask`` mode."""
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(path, 0o666 & ~mask)


def adc_checksum(adcs) -> str:
    """sha256 (hex) of the ADC arrays' complex64 bytes, in order."""
    h = hashlib.sha256()
    for a in adcs:
        h.update(np.ascontiguousarray(a, dtype=np.complex64).tobytes())
    return h.hexdigest()


def write_shard(path, entries: list, adcs: list, digest: str) -> str:
    """Write one shard atomically; returns its checksum."""
    import h5py

    checksum = adc_checksum(adcs)
    with atomic_path(path, suffix=".part") as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = SHARD_FORMAT
            f.attrs["version"] = 1
            f.attrs["dataset"] = digest
            f.attrs["frames"] = json.dumps([e["frame"] for e in entries])
            for e, adc in zip(entries, adcs):
                g = f.create_group(f"frames/{e['frame']:07d}")
                g.create_dataset("adc", data=np.asarray(adc, dtype=np.complex64))
                g.attrs["radar"] = json.dumps(e["radar"])
                g.attrs["pose"] = json.dumps(e["pose"])
                g.attrs["scene"] = json.dumps(e["scene"])
                g.attrs["seed"] = int(e["seed"])
            f.attrs["sha256"] = checksum
            f.attrs["complete"] = True
        make_readable(tmp)
    return checksum


def read_shard(path) -> dict:
    """``frame index -> complex64 ADC`` of a shard."""
    import h5py

    with h5py.File(path, "r") as f:
        return {int(k): f["frames"][k]["adc"][()] for k in f["frames"]}


def shard_is_complete(path, entries: list, digest: str) -> bool:
    """True when ``path`` is a finished shard of exactly ``entries`` of dataset ``digest``
    whose data match its checksum (see module docstring)."""
    import h5py

    if not os.path.isfile(path):
        return False
    try:
        with h5py.File(path, "r") as f:
            a = f.attrs
            if (a.get("format") != SHARD_FORMAT or not bool(a.get("complete", False))
                    or a.get("dataset") != digest
                    or json.loads(a.get("frames", "[]")) != [e["frame"] for e in entries]):
                return False
            adcs = [f["frames"][f"{e['frame']:07d}"]["adc"][()] for e in entries]
            return adc_checksum(adcs) == a.get("sha256")
    except (OSError, KeyError, ValueError):
        return False


def remove_partial_files(folder) -> list:
    """Delete temporary shard files left by a killed writer; returns their paths."""
    stale = glob.glob(os.path.join(os.fspath(folder), ".shard_*.part"))
    for p in stale:
        os.remove(p)
    return stale
