"""ColoRadar-format run folders of generated cases.

Layout written by :func:`write_coloradar_run` (what
:func:`sionna_mmir.captures.coloradar.read_coloradar_run` reads back)::

    <folder>/calib/<sensor>/waveform_cfg.txt   the case's waveform (seconds, Hz)
    <folder>/calib/<sensor>/antenna_cfg.txt    layout in lambda/2 at F_design
    <folder>/calib/transforms/base_to_<sensor>.txt   nominal radar pose in the
                                               scene frame (x y z / qx qy qz qw)
    <folder>/<sensor>/adc_samples/data/frame_<N>.bin  int16 I/Q, C order
                                               [tx][rx][chirp][sample][iq]
    <folder>/<sensor>/adc_samples/timestamps.txt     one time [s] per frame
    <folder>/mesh/<name>.ply                   the user's meshes (scene frame)
    <folder>/truth.json                        name, seed, effects, materials,
                                               nominal radar, the truth

``<sensor>`` is ``cascade`` for a 12 x 16 radar, else ``single_chip``.  The
waveform file holds the exact values of the case's
:class:`~sionna_mmir.radar.RadarConfig` (no unit defects), so the reader
rebuilds the same waveform; its TDM order is the file order, so radars with
another firing order are refused.
"""
from __future__ import annotations

import json
import pathlib

import numpy as np

from ..errors import InputValueError
from .undeclared_adc import C0


def _quaternion_xyzw(rot: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(qx, qy, qz, qw)`` of a rotation matrix."""
    m = np.asarray(rot, float)
    w = np.sqrt(max(0.0, 1.0 + np.trace(m))) / 2.0
    if w > 1e-6:
        return np.array([(m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w),
                         (m[1, 0] - m[0, 1]) / (4 * w), w])
    k = int(np.argmax(np.diag(m)))
    i, j = (k + 1) % 3, (k + 2) % 3
    s = np.sqrt(max(0.0, 1.0 + m[k, k] - m[i, i] - m[j, j])) * 2.0
    q = np.zeros(4)
    q[k], q[i], q[j] = s / 4, (m[i, k] + m[k, i]) / s, (m[j, k] + m[k, j]) / s
    q[3] = (m[j, i] - m[i, j]) / s
    return q / np.linalg.norm(q)


def _half_wavelengths(v: float, hw: float) -> str:
    x = v / hw
    return str(int(round(x))) if abs(x - round(x)) < 1e-9 else repr(float(x))


def _write_calib(radar, calib: pathlib.Path, sensor: str, rot: np.ndarray) -> None:
    wf = {"num_rx": radar.num_rx, "num_tx": radar.num_tx,
          "num_adc_samples_per_chirp": radar.num_samples,
          "num_chirps_per_frame": radar.num_chirps,
          "adc_sample_frequency": radar.sample_rate, "start_frequency": radar.start_frequency,
          "idle_time": radar.idle_time, "adc_start_time": radar.adc_start_time,
          "ramp_end_time": radar.ramp_end_time, "frequency_slope": radar.slope}
    (calib / sensor).mkdir(parents=True, exist_ok=True)
    (calib / sensor / "waveform_cfg.txt").write_text(
        "".join(f"{k} {v!r}\n" for k, v in wf.items()))
    hw = C0 / (2.0 * radar.design_frequency)
    lines = [f"# antenna layout of {radar.name} (generated)",
             "# distances specified in half-wavelengths of F_design",
             f"num_rx {radar.num_rx}", f"num_tx {radar.num_tx}",
             f"F_design {radar.design_frequency / 1e9!r}"]
    for kind, pos in (("rx", radar.rx_positions), ("tx", radar.tx_positions)):
        lines += [f"{kind} {i} {_half_wavelengths(p[1], hw)} {_half_wavelengths(p[2], hw)}"
                  for i, p in enumerate(pos)]
    (calib / sensor / "antenna_cfg.txt").write_text("\n".join(lines) + "\n")
    (calib / "transforms").mkdir(parents=True, exist_ok=True)
    q = _quaternion_xyzw(rot)
    (calib / "transforms" / f"base_to_{sensor}.txt").write_text(
        " ".join(repr(float(v)) for v in radar.position) + "\n"
        + " ".join(repr(float(v)) for v in q) + "\n")


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer, np.floating, np.bool_)):
        return o.item()
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")


def to_int16(frames: np.ndarray) -> tuple:
    """Round complex ADC to int16 I/Q ``[..., 2]``; returns ``(array, n_saturated)``."""
    iq = np.stack([frames.real, frames.imag], -1)
    r = np.rint(iq)
    sat = int(np.count_nonzero((r < -32768) | (r > 32767)))
    return np.clip(r, -32768, 32767).astype("<i2"), sat


def write_coloradar_run(case, folder, overwrite: bool = False) -> pathlib.Path:
    """Write ``case`` (a :class:`~.undeclared.SuiteCase`) as a ColoRadar run folder.

    Parameters
    ----------
    case : SuiteCase
        The generated case; its frames are rounded to int16 counts.
    folder : str or path
        Run folder to create (the layout is in the module docstring).
    overwrite : bool
        Allow writing into an existing non-empty folder.

    Returns
    -------
    pathlib.Path
        ``folder``.  Read it back with ``read_coloradar_run(folder, frame,
        sensor=...)`` (``sensor`` is ``truth.json["sensor"]``).
    """
    from ..radar.config import rotation_matrix

    radar = case.radar_nominal
    if tuple(radar.tdm_order) != tuple(range(radar.num_tx)):
        raise InputValueError(f"write_coloradar_run: TDM order {radar.tdm_order} is not the "
                              f"Tx index order, which ColoRadar's files imply")
    if np.any(radar.tx_positions[:, 0] != 0) or np.any(radar.rx_positions[:, 0] != 0):
        raise InputValueError("write_coloradar_run: antennas off the x = 0 plane cannot be "
                              "written to antenna_cfg.txt")
    root = pathlib.Path(folder)
    if root.exists() and any(root.iterdir()) and not overwrite:
        raise FileExistsError(f"{root} exists and is not empty; pass overwrite=True")
    sensor = "cascade" if (radar.num_tx, radar.num_rx) == (12, 16) else "single_chip"
    _write_calib(radar, root / "calib", sensor, rotation_matrix(radar.orientation))
    data = root / sensor / "adc_samples" / "data"
    data.mkdir(parents=True, exist_ok=True)
    iq, sat = to_int16(case.capture.frames)
    for f in range(iq.shape[0]):
        iq[f].tofile(data / f"frame_{f}.bin")
    period = case.capture.metadata.get("frame_period") or 0.1
    (data.parent / "timestamps.txt").write_text(
        "".join(f"{f * period!r}\n" for f in range(iq.shape[0])))
    (root / "mesh").mkdir(exist_ok=True)
    for name, mesh in case.meshes.items():
        (root / "mesh" / f"{name}.ply").write_bytes(mesh.export(file_type="ply"))
    doc = {"name": case.name, "seed": case.seed, "effects": list(case.effects),
           "sensor": sensor, "materials": case.materials,
           "meshes": {n: f"mesh/{n}.ply" for n in case.meshes},
           "radar_nominal": radar.to_dict(), "int16_saturated_values": sat,
           "truth": case.truth}
    with open(root / "truth.json", "w", encoding="utf-8") as fh:
        json.dump(doc, fh, default=_json_default)
    return root


