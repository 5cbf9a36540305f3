"""The :class:`Capture` container and the project's HDF5 capture format.

HDF5 layout (``format = "sionna_mmir.capture"``, ``version = 1``):

``/adc``
    complex64 ``[n_frames, n_tx, n_rx, n_chirps, n_samples]``
``/@radar``
    JSON of :meth:`RadarConfig.to_dict` (floats round-trip exactly)
``/@metadata``
    JSON of the metadata dict
``/@source``
    where the data came from (file path or ``"synthetic"``)
``/extras/<name>``
    any extra arrays (e.g. TI's ``PeakValMat``)

Files are written to a temporary name and renamed, so a failed write never
leaves a partial file behind.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os

import numpy as np

from ..errors import CaptureFormatError, FrameIndexError, InputValueError
from ..radar.config import RadarConfig
from ..utils.atomic import atomic_path

FORMAT_NAME = "sionna_mmir.capture"
FORMAT_VERSION = 1


@dataclasses.dataclass
class Capture:
    """Raw FMCW ADC of one or more frames with the radar that recorded it.

    ``capture.adc`` is the first frame, ``[n_tx, n_rx, n_chirps, n_samples]``;
    ``capture.frame(i)`` gives a one-frame capture of frame ``i``.

    Parameters
    ----------
    frames : numpy.ndarray
        complex64 ``[n_frames, n_tx, n_rx, n_chirps, n_samples]`` (a single
        frame ``[n_tx, n_rx, n_chirps, n_samples]`` is accepted).
    radar : RadarConfig
        The radar (waveform, layout, pose).
    metadata : dict, optional
        JSON-serialisable metadata (e.g. ``frame_period`` [s]).
    source : str, optional
        File path or ``"synthetic"``.
    extras : dict, optional
        Name -> NumPy array of side information.

    Raises
    ------
    InputValueError
        A shape that is not the radar's ``[tx, rx, chirp, sample]``, or NaN /
        Inf samples.
    """

    frames: np.ndarray
    radar: RadarConfig
    metadata: dict = dataclasses.field(default_factory=dict)
    source: str = "synthetic"
    extras: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        arr = np.asarray(self.frames)
        if arr.ndim == 4:
            arr = arr[None]
        if arr.ndim != 5:
            raise InputValueError(
                f"Capture ({self.source}): ADC must be [tx, rx, chirp, sample] or "
                f"[frame, tx, rx, chirp, sample], got shape {arr.shape}")
        if tuple(arr.shape[1:]) != self.radar.adc_shape:
            raise InputValueError(
                f"Capture ({self.source}): ADC shape {tuple(arr.shape[1:])} does not match "
                f"the radar's [tx, rx, chirp, sample] = {self.radar.adc_shape}")
        if not np.iscomplexobj(arr):
            arr = arr.astype(np.complex64)
        arr = np.ascontiguousarray(arr, dtype=np.complex64)
        if not np.all(np.isfinite(arr.view(np.float32))):
            raise InputValueError(f"Capture ({self.source}): ADC holds NaN or Inf samples")
        self.frames = arr
        self.metadata = dict(self.metadata)
        try:
            check_metadata(self.metadata)
        except InputValueError as e:
            raise InputValueError(f"Capture ({self.source}): {e}") from None
        self.extras = {k: np.asarray(v) for k, v in dict(self.extras).items()}

    # ------------------------------------------------------------- access
    @property
    def adc(self) -> np.ndarray:
        """First frame, complex64 ``[n_tx, n_rx, n_chirps, n_samples]``."""
        return self.frames[0]

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    def frame(self, index: int) -> "Capture":
        """A one-frame :class:`Capture` holding frame ``index``."""
        n = self.num_frames
        if not -n <= int(index) < n:
            raise FrameIndexError(f"Capture ({self.source}) has {n} frames; "
                                  f"frame {index} requested")
        meta = dict(self.metadata, frame_index=int(index) % n)
        return Capture(self.frames[index][None], self.radar, meta, self.source, self.extras)

    # --------------------------------------------------------------- HDF5
    def save(self, path: str | os.PathLike, overwrite: bool = False) -> str:
        """Write the capture to HDF5 (atomically); returns the path.

        Raises ``FileExistsError`` when ``path`` exists and ``overwrite`` is
        False, also when another writer creates it while this one writes
        (the file is moved into place by a hard link, which never replaces).
        """
        import h5py

        path = os.fspath(path)
        if os.path.exists(path) and not overwrite:
            raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
        with atomic_path(path, suffix=".h5.part", overwrite=overwrite) as tmp:
            with h5py.File(tmp, "w") as f:
                f.attrs["format"] = FORMAT_NAME
                f.attrs["version"] = FORMAT_VERSION
                f.attrs["radar"] = json.dumps(self.radar.to_dict())
                f.attrs["metadata"] = json.dumps(self.metadata)
                f.attrs["source"] = str(self.source)
                f.create_dataset("adc", data=self.frames)
                if self.extras:
                    g = f.create_group("extras")
                    for k, v in self.extras.items():
                        g.create_dataset(k, data=v)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Capture":
        """Read a capture written by :meth:`save`.

        The file is checked before its arrays are read: the attributes
        (format, version, radar, metadata), ``adc`` and ``extras/*`` being
        datasets of numbers, ``adc`` having the radar's shape, every part of
        it stored in the file, and the arrays fitting in the available
        memory.

        Raises
        ------
        CaptureFormatError
            Any of these checks failing (the message names the file).
        ResourceError
            Arrays larger than the machine's available memory.
        """
        import h5py

        path = os.fspath(path)
        try:
            f = h5py.File(path, "r")
        except OSError as e:
            raise CaptureFormatError(f"{path}: not a readable HDF5 file ({e})") from None
        with f:
            radar, metadata = _read_header(path, f)
            adc = _dataset(path, f, "adc")
            _check_adc(path, adc, radar)
            extras = {k: _dataset(path, f, f"extras/{k}") for k in _extra_names(path, f)}
            _check_stored(path, [adc, *extras.values()])
            adc = _read(path, adc)
            extras = {k: _read(path, v) for k, v in extras.items()}
            source = _text_attr(f, "source") or path
        return cls(adc, radar, metadata, source, extras)


def _text_attr(f, key: str):
    """An HDF5 attribute as text, or None when absent or not text."""
    value = f.attrs.get(key)
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return value if isinstance(value, str) else None


def _read_header(path: str, f) -> tuple:
    """``(radar, metadata)`` of an open capture file, its format checked."""
    fmt = _text_attr(f, "format")
    if fmt != FORMAT_NAME:
        raise CaptureFormatError(f"{path}: HDF5 file is not a sionna_mmir capture "
                                 f"(attribute 'format' is {f.attrs.get('format')!r})")
    try:
        version = int(f.attrs.get("version", -1))
    except (TypeError, ValueError):
        raise CaptureFormatError(f"{path}: attribute 'version' is not an integer") from None
    if version > FORMAT_VERSION:
        raise CaptureFormatError(f"{path}: capture format version {version} is newer "
                                 f"than this sionna_mmir ({FORMAT_VERSION})")
    texts = {}
    for key in ("radar", "metadata"):
        if key not in f.attrs:
            raise CaptureFormatError(f"{path}: missing attribute {key!r}")
        try:
            texts[key] = json.loads(_text_attr(f, key) or "")
        except json.JSONDecodeError as e:
            raise CaptureFormatError(f"{path}: corrupt JSON attribute {key!r} ({e})") from None
    try:
        radar = RadarConfig.from_dict(texts["radar"])
    except (TypeError, ValueError) as e:               # ConfigError is a ValueError
        raise CaptureFormatError(f"{path}: attribute 'radar': {e}") from None
    metadata = texts["metadata"]
    if not isinstance(metadata, dict):
        raise CaptureFormatError(f"{path}: attribute 'metadata' is not a JSON object")
    try:
        check_metadata(metadata)
    except InputValueError as e:
        raise CaptureFormatError(f"{path}: {e}") from None
    return radar, metadata


def check_metadata(metadata: dict) -> None:
    """Raise :class:`InputValueError` for metadata values of the wrong kind
    (``frame_period`` must be None or a finite number of seconds >= 0)."""
    period = metadata.get("frame_period")
    if period is None:
        return
    ok = isinstance(period, (int, float, np.integer, np.floating)) and not isinstance(period, bool)
    if not ok or not np.isfinite(period) or period < 0:
        raise InputValueError(f"metadata frame_period = {period!r} is not a number of "
                              "seconds >= 0 (or null)")


def _extra_names(path: str, f) -> list:
    if "extras" not in f:
        return []
    import h5py

    if not isinstance(f["extras"], h5py.Group):
        raise CaptureFormatError(f"{path}: 'extras' is not a group")
    return list(f["extras"])


def _dataset(path: str, f, name: str):
    """The dataset ``name``; ``CaptureFormatError`` when it is missing, not a
    dataset, or not numbers."""
    import h5py

    try:
        obj = f.get(name)
    except (KeyError, OSError) as e:                    # a dangling or external link
        raise CaptureFormatError(f"{path}: cannot open {name!r} ({e})") from None
    if obj is None:
        raise CaptureFormatError(f"{path}: missing dataset {name!r}")
    if not isinstance(obj, h5py.Dataset):
        kind = "group" if isinstance(obj, h5py.Group) else type(obj).__name__
        raise CaptureFormatError(f"{path}: {name!r} is a {kind}, not a dataset")
    if obj.dtype.kind not in "biufc":
        raise CaptureFormatError(f"{path}: {name!r} holds {obj.dtype}, not numbers")
    return obj


def _check_adc(path: str, adc, radar: RadarConfig) -> None:
    shape = tuple(adc.shape)
    if len(shape) not in (4, 5) or shape[-4:] != radar.adc_shape:
        raise CaptureFormatError(f"{path}: 'adc' has shape {shape}, expected [frame,] "
                                 f"{radar.adc_shape} [tx, rx, chirp, sample] of its radar")


def _check_stored(path: str, datasets: list) -> None:
    """Every part of each dataset is in the file, and together they fit in memory."""
    from ..utils.memory import array_bytes, check_memory, format_bytes

    total = 0
    for d in datasets:
        if d.shape is None:
            raise CaptureFormatError(f"{path}: {d.name!r} has no data (an empty dataspace)")
        declared = array_bytes(d.shape, d.dtype.itemsize)
        stored = d.id.get_storage_size()
        if d.is_virtual or d.external is not None:      # stored elsewhere: read to see
            whole = True
        elif d.chunks is None:
            whole = stored >= declared
        else:
            whole = d.id.get_num_chunks() >= _chunk_count(d.shape, d.chunks)
        if not whole:
            raise CaptureFormatError(
                f"{path}: {d.name!r} declares {d.shape} ({format_bytes(declared)}) but the file "
                f"stores only {format_bytes(stored)} of it (truncated or never written)")
        # the read, a complex64 copy and the finiteness mask of Capture
        total += declared + array_bytes(d.shape, 8) + array_bytes(d.shape, 2)
    check_memory(total, f"{path}: reading its arrays")


def _chunk_count(shape, chunks) -> int:
    if chunks is None:
        return 0
    return math.prod(-(-int(n) // int(c)) for n, c in zip(shape, chunks))


def _read(path: str, d):
    try:
        return d[()]
    except (OSError, ValueError) as e:  # truncated file, failing filter
        raise CaptureFormatError(f"{path}: cannot read {d.name!r} (truncated?): {e}") from None
