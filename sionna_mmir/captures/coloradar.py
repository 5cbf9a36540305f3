"""ColoRadar raw ADC frames (``frame_N.bin``) -> :class:`Capture`.

``frame_N.bin`` is little-endian int16, I/Q interleaved, C order
``[tx][rx][chirp][sample][iq]`` (cascade 12 x 16 x 16 x 256 x 2 = 3 MiB), with
the Tx/Rx indices of the calibration's ``antenna_cfg.txt``.  A ColoRadar run
keeps them in ``<run>/<sensor>/adc_samples/data/`` next to a
``timestamps.txt`` (one time [s] per frame) one level up; the calibration
folder ``calib/`` sits at the dataset root.

No real ColoRadar frame is available here, so the IQ sign could not be
checked on data: samples are taken as stored (``metadata["iq_conjugated"] =
False``).
"""
from __future__ import annotations

import os
import pathlib
import re

import numpy as np

from ..errors import CaptureFormatError, ConfigError, InputValueError
from ..radar.config import RadarConfig
from .capture import Capture
from .coloradar_calib import _check_sensor, read_coloradar_config

_FRAME_RE = re.compile(r"^frame_(\d+)\.bin$")


def frame_index_from_name(path) -> int | None:
    """``N`` of ``frame_N.bin``, else None."""
    m = _FRAME_RE.match(pathlib.Path(path).name)
    return int(m.group(1)) if m else None


def _timestamps(frame_path: pathlib.Path):
    for folder in (frame_path.parent, frame_path.parent.parent):
        ts = folder / "timestamps.txt"
        if ts.is_file():
            try:
                return np.loadtxt(ts, ndmin=1, dtype=np.float64), ts
            except ValueError:
                return None, ts
    return None, None


def read_coloradar_frame(path, radar: RadarConfig) -> Capture:
    """Read one ColoRadar ``frame_N.bin`` with the given radar.

    ``radar`` is usually ``read_coloradar_config(calib_dir, sensor)``.
    Returns a one-frame :class:`Capture`, complex64 ``[1, n_tx, n_rx,
    num_chirps, num_samples]`` in ADC counts.  ``metadata`` holds ``file``,
    ``frame_index`` (from the name), ``timestamp`` [s] and ``frame_period``
    [s] when a ``timestamps.txt`` is found beside or above the file, else
    ``frame_period`` None.  A file whose size is not ``2 * 2 * n_tx * n_rx *
    num_chirps * num_samples`` bytes raises :class:`CaptureFormatError`.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such file")
    if not isinstance(radar, RadarConfig):
        raise InputValueError(f"read_coloradar_frame({path}): radar must be a RadarConfig, "
                              f"got {type(radar).__name__}")
    shape = radar.adc_shape
    expected = 4 * int(np.prod(shape))
    size = os.path.getsize(path)
    if size != expected:
        raise CaptureFormatError(
            f"{path}: size {size} bytes, expected {expected} bytes for int16 I/Q "
            f"[tx {shape[0]}][rx {shape[1]}][chirp {shape[2]}][sample {shape[3]}][2] "
            f"of radar {radar.name!r}")
    raw = np.fromfile(path, dtype="<i2").astype(np.float32).reshape(shape + (2,))
    adc = (raw[..., 0] + 1j * raw[..., 1]).astype(np.complex64)
    index = frame_index_from_name(path)
    meta = {"file": os.path.basename(path), "format": "coloradar_frame",
            "frame_index": index, "frame_period": None, "iq_conjugated": False}
    ts, ts_path = _timestamps(pathlib.Path(path))
    if ts is not None and index is not None and index < ts.size:
        meta["timestamp"] = float(ts[index])
        if ts.size > 1:
            meta["frame_period"] = float(np.median(np.diff(ts)))
        meta["timestamps_file"] = os.fspath(ts_path)
    return Capture(adc, radar, meta, source=path)


def find_calib_dir(start, sensor: str = "cascade") -> pathlib.Path | None:
    """First ``calib/`` folder holding ``<sensor>/waveform_cfg.txt`` in ``start`` or above."""
    p = pathlib.Path(start).resolve()
    if p.is_file():
        p = p.parent
    for folder in (p, *p.parents):
        for cand in (folder / "calib", folder):
            if (cand / sensor / "waveform_cfg.txt").is_file():
                return cand
    return None


def find_frame_file(run_dir, frame: int = 0, sensor: str = "cascade") -> pathlib.Path:
    """Locate ``frame_<frame>.bin`` for ``sensor`` in a ColoRadar run folder.

    Looks in ``run_dir``, ``run_dir/<sensor>/adc_samples/data``,
    ``run_dir/<sensor>/adc_samples``, ``run_dir/<sensor>``,
    ``run_dir/adc_samples/data``, ``run_dir/adc_samples``, ``run_dir/data``,
    then anywhere below ``run_dir`` (preferring paths through a ``<sensor>``
    folder).  Raises ``FileNotFoundError`` listing what was searched.
    """
    run = pathlib.Path(run_dir)
    name = f"frame_{int(frame)}.bin"
    subdirs = [".", f"{sensor}/adc_samples/data", f"{sensor}/adc_samples", sensor,
               "adc_samples/data", "adc_samples", "data"]
    for sub in subdirs:
        cand = run / sub / name
        if cand.is_file():
            return cand
    found = sorted(run.rglob(name))
    if found:
        with_sensor = [f for f in found if sensor in f.relative_to(run).parts]
        other = [f for f in found if sensor not in f.relative_to(run).parts and
                 not any(s in f.relative_to(run).parts for s in ("cascade", "single_chip"))]
        for group in (with_sensor, other):
            if group:
                return group[0]
    raise FileNotFoundError(
        f"{run}: no {name} for sensor {sensor!r}; searched "
        + ", ".join(os.fspath(run / s) for s in subdirs) + f" and every folder below {run}")


def read_coloradar_run(run_dir, frame: int = 0, calib_dir=None,
                       sensor: str = "cascade") -> Capture:
    """Read frame ``frame`` of ``sensor`` from a ColoRadar run folder.

    The radar is ``read_coloradar_config(calib_dir, sensor)`` (see
    :func:`~sionna_mmir.captures.coloradar_calib.read_coloradar_config`).

    Parameters
    ----------
    run_dir : str or os.PathLike
        Run folder (e.g. ``.../2_28_2021_outdoors_run0``).
    frame : int, optional
        Frame index ``N`` of ``frame_N.bin``.
    calib_dir : str or os.PathLike, optional
        ColoRadar ``calib`` folder; default: a ``calib/`` found in
        ``run_dir`` or one of its parents.
    sensor : {"cascade", "single_chip"}, optional
        The ColoRadar sensor.

    Returns
    -------
    Capture
        One frame (see :func:`read_coloradar_frame`).
    """
    sensor = _check_sensor(sensor)
    run = pathlib.Path(run_dir)
    if not run.is_dir():
        raise FileNotFoundError(f"{run}: ColoRadar run folder not found")
    if int(frame) != frame or int(frame) < 0:
        raise InputValueError(f"read_coloradar_run({run}): frame must be a non-negative "
                              f"integer, got {frame!r}")
    frame_path = find_frame_file(run, int(frame), sensor)
    radar, calib_dir = coloradar_radar(run, calib_dir, sensor)
    cap = read_coloradar_frame(frame_path, radar)
    cap.metadata["calib_dir"] = os.fspath(calib_dir)
    cap.metadata["sensor"] = sensor
    return cap


def coloradar_radar(where, calib_dir=None, sensor: str = "cascade"):
    """``(RadarConfig, calib_dir)`` for ColoRadar data in folder ``where``.

    ``calib_dir`` defaults to a ``calib/`` folder found in ``where`` or a
    parent; none found -> :class:`ConfigError` naming what was searched.
    """
    if calib_dir is None:
        calib_dir = find_calib_dir(where, sensor)
        if calib_dir is None:
            raise ConfigError(f"{where}: no ColoRadar calibration found (looked for "
                              f"calib/{sensor}/waveform_cfg.txt in {where} and each parent "
                              f"folder); pass calib_dir or radar")
    return read_coloradar_config(calib_dir, sensor), calib_dir
