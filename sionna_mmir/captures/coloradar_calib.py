"""ColoRadar calibration folder: waveform, antennas, coupling, phase/frequency, extrinsics.

Folder layout (``<calib_dir>``)::

    cascade/      waveform_cfg.txt antenna_cfg.txt coupling_calib.txt
                  heatmap_cfg.txt phase_frequency_calib.txt
    single_chip/  waveform_cfg.txt antenna_cfg.txt coupling_calib.txt heatmap_cfg.txt
    transforms/   base_to_<sensor>.txt

Index conventions (verified on the stored files)
------------------------------------------------
* Tx / Rx indices are those of ``antenna_cfg.txt`` (the ``IDX`` column), which
  is also the ``[tx][rx]`` order of ColoRadar's ``frame_N.bin``.  For the
  cascade this is *not* TI's device order: file Tx 0..11 sit at azimuth
  0, 4, 8, 9, 10, 11, 12, 16, ..., 32 (device Tx 12, 11, 10, 3, 2, 1, 9, 8, 7,
  6, 5, 4) and file Rx 0..15 at 0..3, 11..14, 46..49, 50..53 (device Rx 13-16,
  1-4, 9-12, 5-8).
* ``coupling_calib.txt`` is ``[tx][rx][range_bin]`` with the range bin
  fastest: every block of ``num_range_bins`` values decays from a strong first
  bin (leakage) to noise, and reshaped tx-major the leakage power is
  block-diagonal by chip (file Tx 3k..3k+2 couple most into file Rx 4k..4k+3,
  the Tx and Rx of one AWR2243), which the rx-major reshape does not show.
  The stored single-chip table has its third Tx block all zeros.
* ``phase_frequency_calib.txt`` lists the 192 channels tx-major
  (``index = tx * num_rx + rx``): reshaped so, the peak bins follow an additive
  ``tx + rx`` model twice as well as rx-major, with the 4-Rx / 3-Tx per-chip
  grouping visible in both axes.
"""
from __future__ import annotations

import dataclasses
import json
import os
import warnings

import numpy as np

from ..errors import CaptureFormatError, ConfigError, InputValueError
from ..processing.calibration import phase_frequency_correct, subtract_coupling
from ..processing.range_fft import range_fft
from ..radar.config import RadarConfig

SENSORS = ("cascade", "single_chip")

WAVEFORM_KEYS = ("num_rx", "num_tx", "num_adc_samples_per_chirp", "num_chirps_per_frame",
                 "adc_sample_frequency", "start_frequency", "idle_time", "adc_start_time",
                 "ramp_end_time", "frequency_slope")
_TIME_KEYS = ("idle_time", "adc_start_time", "ramp_end_time")
_MICROSECOND_THRESHOLD = 1e-3   # a "time" above 1 ms is taken to be in microseconds


class ColoRadarRepairWarning(UserWarning):
    """A known defect of a stored ColoRadar waveform file was repaired."""


def _check_sensor(sensor) -> str:
    if sensor not in SENSORS:
        raise ConfigError(f"ColoRadar sensor {sensor!r} is unknown; choose one of "
                          f"{', '.join(repr(s) for s in SENSORS)}")
    return sensor


def _read_lines(path: str):
    if not os.path.isfile(path):
        raise ConfigError(f"{path}: file not found")
    try:
        with open(path, "r", encoding="utf-8") as fh:
            return fh.read().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read ({e})") from None


def _number(path, lineno, key, text):
    try:
        v = float(text)
    except ValueError:
        raise ConfigError(f"{path}:{lineno}: key {key!r} has a non-numeric value "
                          f"{text!r}") from None
    if not np.isfinite(v):
        raise ConfigError(f"{path}:{lineno}: key {key!r} is not finite ({text!r})")
    return v


def _integer(path, lineno, key, text):
    v = _number(path, lineno, key, text)
    if v != int(v) or v < 1:
        raise ConfigError(f"{path}:{lineno}: key {key!r} must be a positive integer, got {text!r}")
    return int(v)


def read_waveform_cfg(path) -> dict:
    """Parse ``waveform_cfg.txt`` (``key value`` lines) into a dict of floats/ints.

    All ten keys of :data:`WAVEFORM_KEYS` are required; unknown or duplicate
    keys and lines that are not ``key value`` raise :class:`ConfigError` naming
    the file, the line number and the key.  Values are returned as stored (no
    unit repair; see :func:`read_coloradar_config`).
    """
    path = os.fspath(path)
    out, where = {}, {}
    for lineno, raw in enumerate(_read_lines(path), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 2:
            raise ConfigError(f"{path}:{lineno}: malformed line {raw.strip()!r} "
                              f"(expected 'key value')")
        key, text = parts
        if key not in WAVEFORM_KEYS:
            raise ConfigError(f"{path}:{lineno}: unknown key {key!r} (known keys: "
                              f"{', '.join(WAVEFORM_KEYS)})")
        if key in out:
            raise ConfigError(f"{path}:{lineno}: key {key!r} repeated (first on line {where[key]})")
        if key.startswith("num_"):
            out[key] = _integer(path, lineno, key, text)
        else:
            out[key] = _number(path, lineno, key, text)
        where[key] = lineno
    missing = [k for k in WAVEFORM_KEYS if k not in out]
    if missing:
        raise ConfigError(f"{path}: missing required key(s) {', '.join(missing)}")
    return out


def read_antenna_cfg(path) -> dict:
    """Parse ``antenna_cfg.txt``.

    Returns ``{"num_rx", "num_tx", "F_design" [GHz], "tx": [n_tx, 2], "rx":
    [n_rx, 2]}`` with rows ordered by the file's index column and columns
    ``(X, Y)`` in half-wavelengths at ``F_design`` (X = azimuth, Y = elevation).
    Every index ``0..n-1`` must appear exactly once.
    """
    path = os.fspath(path)
    head, elems = {}, {"tx": {}, "rx": {}}
    for lineno, raw in enumerate(_read_lines(path), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        key = parts[0]
        if key in ("num_rx", "num_tx", "F_design"):
            if len(parts) != 2:
                raise ConfigError(f"{path}:{lineno}: malformed line {raw.strip()!r} "
                                  f"(expected '{key} value')")
            if key in head:
                raise ConfigError(f"{path}:{lineno}: key {key!r} repeated")
            head[key] = (_integer(path, lineno, key, parts[1]) if key.startswith("num_")
                         else _number(path, lineno, key, parts[1]))
        elif key in ("tx", "rx"):
            if len(parts) != 4:
                raise ConfigError(f"{path}:{lineno}: malformed line {raw.strip()!r} "
                                  f"(expected '{key} IDX X Y')")
            try:
                idx = int(parts[1])
            except ValueError:
                raise ConfigError(f"{path}:{lineno}: {key} index {parts[1]!r} is not an "
                                  f"integer") from None
            if idx in elems[key]:
                raise ConfigError(f"{path}:{lineno}: {key} index {idx} repeated")
            elems[key][idx] = (_number(path, lineno, f"{key} {idx} X", parts[2]),
                               _number(path, lineno, f"{key} {idx} Y", parts[3]))
        else:
            raise ConfigError(f"{path}:{lineno}: unknown key {key!r} (expected num_rx, num_tx, "
                              f"F_design, tx or rx)")
    missing = [k for k in ("num_rx", "num_tx", "F_design") if k not in head]
    if missing:
        raise ConfigError(f"{path}: missing required key(s) {', '.join(missing)}")
    if head["F_design"] <= 0:
        raise ConfigError(f"{path}: F_design must be positive, got {head['F_design']}")
    out = dict(head)
    for kind in ("tx", "rx"):
        n = head[f"num_{kind}"]
        if sorted(elems[kind]) != list(range(n)):
            raise ConfigError(f"{path}: {kind} indices {sorted(elems[kind])} do not cover "
                              f"0..{n - 1} (num_{kind} {n})")
        out[kind] = np.array([elems[kind][i] for i in range(n)], dtype=np.float64)
    return out


def _repair_times(path, wf: dict) -> list:
    """Repair the known unit defects in place; returns human-readable notes."""
    notes = []
    for key in _TIME_KEYS:
        if wf[key] > _MICROSECOND_THRESHOLD:
            old = wf[key]
            wf[key] = old * 1e-6
            notes.append(f"{path}: {key} {old!r} > 1 ms taken as microseconds -> {wf[key]!r} s")
    adc_end = wf["adc_start_time"] + wf["num_adc_samples_per_chirp"] / wf["adc_sample_frequency"]
    if wf["ramp_end_time"] < adc_end * (1 - 1e-6):
        old = wf["ramp_end_time"]
        fixed = old * 1e6
        if not (adc_end * (1 - 1e-6) <= fixed <= _MICROSECOND_THRESHOLD):
            raise ConfigError(
                f"{path}: ramp_end_time {old!r} s cannot contain the ADC window ending at "
                f"{adc_end * 1e6:.3f} us (adc_start_time + num_adc_samples_per_chirp / "
                f"adc_sample_frequency), not even scaled by 1e6")
        wf["ramp_end_time"] = fixed
        notes.append(f"{path}: ramp_end_time {old!r} s ends before the ADC window "
                     f"({adc_end * 1e6:.3f} us); scaled by 1e6 -> {fixed!r} s")
    return notes


def read_coloradar_config(calib_dir, sensor: str = "cascade", **overrides) -> RadarConfig:
    """Build a :class:`RadarConfig` from ``<calib_dir>/<sensor>/{waveform,antenna}_cfg.txt``.

    Parameters
    ----------
    calib_dir : str or os.PathLike
        ColoRadar ``calib`` folder (holding ``cascade/``, ...).
    sensor : {"cascade", "single_chip"}
        Which sensor.
    **overrides
        RadarConfig fields to replace (e.g. ``num_chirps=1``).

    Units: the file's times are seconds, frequencies Hz, slope Hz/s; antenna
    positions are half-wavelengths at ``F_design`` GHz and become
    ``(0, X lambda_d / 2, Y lambda_d / 2)`` metres (X azimuth -> +y, Y
    elevation -> +z).  Tx/Rx indices and the TDM order are the file's order.

    Repairs (reported with a :class:`ColoRadarRepairWarning` and stored as
    the ``notes`` field of the returned config, which is
    serialised): a time (idle, ADC start, ramp end) above 1 ms is taken to be
    in microseconds (the cascade's ``adc_start_time 6.0`` -> 6 us); a
    ``ramp_end_time`` that ends before the ADC window is scaled by 1e6 (the
    cascade's ``3.99999998402e-11`` -> 40 us) and must then contain the
    window, else :class:`ConfigError`.
    """
    sensor = _check_sensor(sensor)
    calib_dir = os.fspath(calib_dir)
    folder = os.path.join(calib_dir, sensor)
    if not os.path.isdir(folder):
        raise ConfigError(f"{folder}: ColoRadar calibration folder for sensor {sensor!r} "
                          f"not found (calib_dir {calib_dir})")
    wf_path = os.path.join(folder, "waveform_cfg.txt")
    ant_path = os.path.join(folder, "antenna_cfg.txt")
    wf = read_waveform_cfg(wf_path)
    ant = read_antenna_cfg(ant_path)
    for kind in ("num_tx", "num_rx"):
        if wf[kind] != ant[kind]:
            raise ConfigError(f"{wf_path}: {kind} {wf[kind]} disagrees with {ant_path} "
                              f"({ant[kind]})")
    notes = _repair_times(wf_path, wf)
    params = dict(start_frequency=wf["start_frequency"], slope=wf["frequency_slope"],
                  sample_rate=wf["adc_sample_frequency"],
                  num_samples=wf["num_adc_samples_per_chirp"],
                  num_chirps=wf["num_chirps_per_frame"], idle_time=wf["idle_time"],
                  adc_start_time=wf["adc_start_time"], ramp_end_time=wf["ramp_end_time"],
                  tdm_order=tuple(range(wf["num_tx"])), name=f"coloradar_{sensor}")
    known = {f.name for f in dataclasses.fields(RadarConfig)} - {"tx_positions", "rx_positions",
                                                         "design_frequency"}
    bad = sorted(set(overrides) - known)
    if bad:
        raise ConfigError(f"read_coloradar_config: unknown override(s) {bad}; allowed: "
                          f"{sorted(known)}")
    params.update(overrides)
    try:
        cfg = RadarConfig._from_layout(ant["tx"], ant["rx"], ant["F_design"] * 1e9, **params)
    except ConfigError as e:
        raise ConfigError(f"{folder}: {e}") from None
    cfg.notes = tuple(notes)
    if notes:
        warnings.warn("; ".join(notes), ColoRadarRepairWarning, stacklevel=2)
    return cfg


# ------------------------------------------------------------------ coupling
def read_coupling_calib(path) -> np.ndarray:
    """Read ``coupling_calib.txt``: complex128 ``[num_tx, num_rx, num_range_bins]``.

    Header lines ``num_tx:``, ``num_rx:``, ``num_range_bins:``,
    ``num_doppler_bins:`` then ``data:`` with comma-separated ``re,im`` pairs,
    tx-major with the range bin fastest (see the module docstring for the
    check of this order).  Values are in the range-FFT domain of ColoRadar's
    processing (arbitrary ADC units).  A wrong number of values raises
    :class:`CaptureFormatError` with the expected and found counts; missing or
    malformed header keys raise :class:`ConfigError`.
    """
    path = os.fspath(path)
    head, data, data_line = {}, None, None
    for lineno, raw in enumerate(_read_lines(path), start=1):
        line = raw.strip()
        if not line:
            continue
        if ":" not in line:
            raise ConfigError(f"{path}:{lineno}: malformed line {line[:60]!r} "
                              f"(expected 'key:value')")
        key, text = (s.strip() for s in line.split(":", 1))
        if key == "data":
            data, data_line = text, lineno
        elif key in ("num_tx", "num_rx", "num_range_bins", "num_doppler_bins"):
            head[key] = _integer(path, lineno, key, text)
        else:
            raise ConfigError(f"{path}:{lineno}: unknown key {key!r}")
    missing = [k for k in ("num_tx", "num_rx", "num_range_bins") if k not in head]
    if missing:
        raise ConfigError(f"{path}: missing required key(s) {', '.join(missing)}")
    if data is None:
        raise CaptureFormatError(f"{path}: no 'data:' line")
    try:
        vals = np.array([float(v) for v in data.strip().strip(",").split(",")], dtype=np.float64)
    except ValueError as e:
        raise CaptureFormatError(f"{path}:{data_line}: non-numeric coupling value ({e})") from None
    shape = (head["num_tx"], head["num_rx"], head["num_range_bins"])
    expected = 2 * int(np.prod(shape))
    if vals.size != expected:
        raise CaptureFormatError(
            f"{path}: {vals.size} numbers after 'data:', expected {expected} "
            f"(re,im for num_tx {shape[0]} x num_rx {shape[1]} x num_range_bins {shape[2]})")
    if not np.all(np.isfinite(vals)):
        raise CaptureFormatError(f"{path}: coupling data holds NaN or Inf")
    return (vals[0::2] + 1j * vals[1::2]).reshape(shape)


# ---------------------------------------------------------- phase / frequency
@dataclasses.dataclass
class PhaseFrequencyCalib:
    """ColoRadar cascade phase/frequency calibration (corner reflector).

    Indices are ColoRadar file order (tx-major in the file).  The correction
    for channel ``i`` relative to channel 0 is ``p_0 / p_i`` (unit modulus)
    and ``exp(-j 2 pi (b_i - b_0) / (I N) (S / S_cal) (f_s,cal / f_s) n)``
    (see :mod:`sionna_mmir.processing.calibration`).

    Caution on the bin unit: the stored bins are ~51.2.  Read as bins of an
    ``I N = 1280``-point FFT they put the corner at ~0.61 m; read as bins of
    the plain ``N = 256``-point FFT (``interp_factor = 1``) at ~3.04 m, which
    is where ColoRadar's corner stood ("about 3 m").  Their channel spread
    (std 0.12) is also that of TI's per-channel peaks in N-bin units, so the
    values look like N-point bins with sub-bin interpolation.
    :meth:`corner_range` shows the implied corner distance for a choice of
    ``interp_factor``.

    Parameters
    ----------
    frequency_bins : numpy.ndarray
        float64 ``[num_tx, num_rx]`` corner peak bins, as stored.
    phase : numpy.ndarray
        complex128 ``[num_tx, num_rx]`` complex peak values.
    slope : float
        Calibration chirp slope [Hz/s].
    sample_rate : float
        Calibration sample rate [Hz].
    interp_factor : int, optional
        Zero-padding factor ``I`` the bins are said to refer to.
    num_samples : int, optional
        Samples per chirp ``N`` of the calibration capture.
    source : str, optional
        File the values came from.
    """

    frequency_bins: np.ndarray
    phase: np.ndarray
    slope: float
    sample_rate: float
    interp_factor: int = 5
    num_samples: int = 256
    source: str = ""

    @property
    def num_tx(self) -> int:
        return int(self.frequency_bins.shape[0])

    @property
    def num_rx(self) -> int:
        return int(self.frequency_bins.shape[1])

    def phase_correction(self, reference=(0, 0)) -> np.ndarray:
        """Unit-modulus ``p_ref / p_i``, complex128 ``[num_tx, num_rx]``."""
        c = self.phase[reference] / self.phase
        return c / np.abs(c)

    def corner_range(self, interp_factor: int | None = None) -> np.ndarray:
        """Corner distance [m] implied by each bin, ``[num_tx, num_rx]``.

        ``R = b f_s c / (2 S I N)`` with ``I = interp_factor`` (default the
        stored one).
        """
        i = self.interp_factor if interp_factor is None else int(interp_factor)
        return self.frequency_bins * self.sample_rate * 299_792_458.0 / (
            2.0 * self.slope * i * self.num_samples)


def read_phase_frequency_calib(path, num_samples: int = 256,
                               interp_factor: int = 5) -> PhaseFrequencyCalib:
    """Read ColoRadar's ``phase_frequency_calib.txt`` (JSON ``antennaCalib``).

    ``frequencyCalibrationMatrix`` (``numTx * numRx`` floats) and
    ``phaseCalibrationMatrix`` (``2 * numTx * numRx`` floats, ``re, im``
    pairs) are reshaped tx-major to ``[numTx, numRx]``.  ``num_samples`` is
    the calibration's ``N`` (not in the file; 256 for the cascade).  Bad JSON,
    missing keys or wrong lengths raise :class:`ConfigError` naming the file.
    """
    path = os.fspath(path)
    text = "\n".join(_read_lines(path))
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise ConfigError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("antennaCalib"), dict):
        raise ConfigError(f"{path}: missing object 'antennaCalib'")
    ac = doc["antennaCalib"]
    keys = ("numTx", "numRx", "frequencySlope", "samplingRate", "frequencyCalibrationMatrix",
            "phaseCalibrationMatrix")
    missing = [k for k in keys if k not in ac]
    if missing:
        raise ConfigError(f"{path}: antennaCalib lacks key(s) {', '.join(missing)}")
    try:
        nt, nr = int(ac["numTx"]), int(ac["numRx"])
        slope, fs = float(ac["frequencySlope"]), float(ac["samplingRate"])
        fb = np.asarray(ac["frequencyCalibrationMatrix"], dtype=np.float64)
        pv = np.asarray(ac["phaseCalibrationMatrix"], dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{path}: antennaCalib holds non-numeric values ({e})") from None
    if nt < 1 or nr < 1 or slope == 0 or fs <= 0:
        raise ConfigError(f"{path}: numTx/numRx/samplingRate must be positive and "
                          f"frequencySlope non-zero")
    if fb.ndim != 1 or fb.size != nt * nr:
        raise ConfigError(f"{path}: frequencyCalibrationMatrix has {fb.size} values, expected "
                          f"numTx x numRx = {nt * nr}")
    if pv.ndim != 1 or pv.size != 2 * nt * nr:
        raise ConfigError(f"{path}: phaseCalibrationMatrix has {pv.size} values, expected "
                          f"2 x numTx x numRx = {2 * nt * nr} (re, im pairs)")
    if not (np.all(np.isfinite(fb)) and np.all(np.isfinite(pv))):
        raise ConfigError(f"{path}: calibration matrices hold NaN or Inf")
    phase = (pv[0::2] + 1j * pv[1::2]).reshape(nt, nr)
    if np.any(phase == 0):
        raise ConfigError(f"{path}: phaseCalibrationMatrix holds zero peak values")
    if int(num_samples) < 1 or int(interp_factor) < 1:
        raise ConfigError(f"{path}: num_samples and interp_factor must be positive")
    return PhaseFrequencyCalib(fb.reshape(nt, nr), phase, slope, fs, int(interp_factor),
                               int(num_samples), path)


# ------------------------------------------------------------ heatmap / pose
def read_heatmap_cfg(path) -> dict:
    """Read ``heatmap_cfg.txt``.

    Returns ``{"num_range_bins": int, "num_elevation_bins": int,
    "num_azimuth_bins": int, "range_bin_width": float [m],
    "azimuth_bins": float64 [num_azimuth_bins] [rad],
    "elevation_bins": float64 [num_elevation_bins] [rad]}``.  Bin lists must
    have the announced lengths.
    """
    path = os.fspath(path)
    ints = ("num_range_bins", "num_elevation_bins", "num_azimuth_bins")
    out = {}
    for lineno, raw in enumerate(_read_lines(path), start=1):
        parts = raw.split()
        if not parts:
            continue
        key = parts[0]
        if key in out:
            raise ConfigError(f"{path}:{lineno}: key {key!r} repeated")
        if key in ints or key == "range_bin_width":
            if len(parts) != 2:
                raise ConfigError(f"{path}:{lineno}: malformed line for {key!r} "
                                  f"(expected one value)")
            out[key] = (_integer(path, lineno, key, parts[1]) if key in ints
                        else _number(path, lineno, key, parts[1]))
        elif key in ("azimuth_bins", "elevation_bins"):
            out[key] = np.array([_number(path, lineno, key, t) for t in parts[1:]])
        else:
            raise ConfigError(f"{path}:{lineno}: unknown key {key!r}")
    need = ints + ("range_bin_width", "azimuth_bins", "elevation_bins")
    missing = [k for k in need if k not in out]
    if missing:
        raise ConfigError(f"{path}: missing required key(s) {', '.join(missing)}")
    for kind in ("azimuth", "elevation"):
        n, arr = out[f"num_{kind}_bins"], out[f"{kind}_bins"]
        if arr.size != n:
            raise ConfigError(f"{path}: {kind}_bins has {arr.size} values, "
                              f"num_{kind}_bins is {n}")
    return out


def read_transform(path):
    """Read ``transforms/base_to_*.txt``: ``(translation [3] m, quaternion [4] xyzw)``.

    Line 1 ``x y z``, line 2 ``qx qy qz qw``.  The quaternion must be of unit
    norm (within 1e-3).
    """
    path = os.fspath(path)
    rows = [(i, r.split()) for i, r in enumerate(_read_lines(path), start=1) if r.strip()]
    if len(rows) != 2 or len(rows[0][1]) != 3 or len(rows[1][1]) != 4:
        raise ConfigError(f"{path}: expected two lines 'x y z' and 'qx qy qz qw'")
    t = np.array([_number(path, rows[0][0], "translation", v) for v in rows[0][1]])
    q = np.array([_number(path, rows[1][0], "quaternion", v) for v in rows[1][1]])
    if abs(np.linalg.norm(q) - 1.0) > 1e-3:
        raise ConfigError(f"{path}:{rows[1][0]}: quaternion norm {np.linalg.norm(q):.6f} is not 1")
    return t, q


# ------------------------------------------------------- applying the calibration
# ColoRadar's measured calibration applied to a capture, from its calib folder:
# 1. phase / frequency correction of the raw ADC from
#    ``cascade/phase_frequency_calib.txt`` (cascade only; the single chip has
#    none), with ``interp_factor = 1`` by default because the stored bins read
#    as plain 256-point bins (corner at 3.04 m, as documented; see
#    ``PhaseFrequencyCalib.corner_range``);
# 2. coupling subtraction in the range-FFT domain from ``coupling_calib.txt``,
#    on the first ``num_range_bins`` bins of every chirp's *unwindowed*
#    ``num_samples``-point range FFT (ColoRadar's convention is not documented
#    in the files; a rectangular window is our assumption).

def coloradar_phase_frequency_correct(adc, radar: RadarConfig, calib_dir, interp_factor: int = 1):
    """Phase/frequency-correct cascade ADC ``[tx, rx, chirp, sample]`` (ColoRadar order)."""
    path = os.path.join(os.fspath(calib_dir), "cascade", "phase_frequency_calib.txt")
    cal = read_phase_frequency_calib(path)
    if cal.phase.shape != (radar.num_tx, radar.num_rx):
        raise InputValueError(f"{path}: calibration is {cal.phase.shape} [tx, rx] but the radar "
                              f"has {radar.num_tx} x {radar.num_rx}")
    return phase_frequency_correct(adc, radar, cal.frequency_bins, cal.phase, cal.slope,
                                   cal.sample_rate, cal.num_samples, interp_factor=interp_factor)


def coloradar_range_fft(adc, radar: RadarConfig, calib_dir, sensor: str = "cascade",
                        phase_frequency: bool = True, interp_factor: int = 1):
    """Calibrated range spectrum ``[tx, rx, chirp, num_samples]`` (rectangular window).

    Applies the phase/frequency correction (cascade, optional) and subtracts
    the measured coupling from the first bins.
    """
    x = np.asarray(adc)
    if sensor == "cascade" and phase_frequency:
        x = coloradar_phase_frequency_correct(x, radar, calib_dir, interp_factor)
    path = os.path.join(os.fspath(calib_dir), sensor, "coupling_calib.txt")
    coupling = read_coupling_calib(path)
    spec, _ = range_fft(x, radar, window="rect")
    return subtract_coupling(spec, coupling)


def _quaternion_matrix(q) -> np.ndarray:
    """Rotation matrix of a quaternion ``(qx, qy, qz, qw)`` (normalised first)."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def euler_from_matrix(R) -> tuple:
    """``(yaw, pitch, roll)`` [rad] of ``R = Rz(yaw) Ry(pitch) Rx(roll)``
    (:func:`sionna_mmir.radar.config.rotation_matrix`'s convention)."""
    R = np.asarray(R, dtype=float)
    return (float(np.arctan2(R[1, 0], R[0, 0])),
            float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))),
            float(np.arctan2(R[2, 1], R[2, 2])))


def coloradar_pose(calib_dir, sensor: str = "cascade"):
    """The sensor's pose from ``<calib_dir>/transforms/base_to_<sensor>.txt``.

    Read as the radar's pose in the frame of the run's meshes (the base
    frame), in the package's radar convention (``+x`` boresight, ``+y``
    left, ``+z`` up).

    Returns
    -------
    tuple
        ``(position [3] m, orientation (yaw, pitch, roll) [rad])``, or
        ``None`` when the file is absent.
    """
    sensor = _check_sensor(sensor)
    path = os.path.join(os.fspath(calib_dir), "transforms", f"base_to_{sensor}.txt")
    if not os.path.exists(path):
        return None
    t, q = read_transform(path)
    return tuple(float(v) for v in t), euler_from_matrix(_quaternion_matrix(q))


def colocated_pose(position, orientation, calib_dir, sensor: str = "single_chip",
                   reference: str = "cascade"):
    """Pose of ``sensor`` when ``reference`` sits at ``(position, orientation)``.

    The mounting of both sensors on the ColoRadar rig
    (``transforms/base_to_<sensor>.txt``) gives ``sensor``'s pose relative to
    ``reference``: offset ``d = R_ref^T (t_sensor - t_ref)`` and rotation
    ``R_ref^T R_sensor`` in the reference radar's frame.  Composed with the
    reference's pose: ``p = position + R d``, ``R_sensor = R R_ref^T R_sensor``
    (``R`` = :func:`~sionna_mmir.radar.config.rotation_matrix` of
    ``orientation``).

    Parameters
    ----------
    position : array_like
        ``(3,)`` reference radar position [m].
    orientation : array_like
        ``(3,)`` reference ``(yaw, pitch, roll)`` [rad].
    calib_dir : str or os.PathLike
        ColoRadar calibration folder (with ``transforms/``).
    sensor, reference : {"cascade", "single_chip"}
        The sensor to place and the one whose pose is given.

    Returns
    -------
    tuple
        ``(position (3,) ndarray [m], orientation (yaw, pitch, roll) [rad])``.

    Raises
    ------
    ConfigError
        A transform file is missing or unreadable, or an unknown sensor.
    """
    from ..radar.config import rotation_matrix

    poses = {}
    for name in (sensor, reference):
        path = os.path.join(os.fspath(calib_dir), "transforms", f"base_to_{_check_sensor(name)}.txt")
        if not os.path.exists(path):
            raise ConfigError(f"{path}: file not found (needed for the {name} mounting)")
        t, q = read_transform(path)
        poses[name] = (t, _quaternion_matrix(q))
    (t_s, R_s), (t_r, R_r) = poses[sensor], poses[reference]
    R = rotation_matrix(orientation)
    p = np.asarray(position, dtype=float) + R @ (R_r.T @ (t_s - t_r))
    return p, euler_from_matrix(R @ R_r.T @ R_s)
