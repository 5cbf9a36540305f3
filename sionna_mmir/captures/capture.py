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
import os

import numpy as np

from ..errors import CaptureFormatError, InputValueError
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
            raise IndexError(f"Capture ({self.source}) has {n} frames; frame {index} requested")
        meta = dict(self.metadata, frame_index=int(index) % n)
        return Capture(self.frames[index][None], self.radar, meta, self.source, self.extras)

    # --------------------------------------------------------------- HDF5
    def save(self, path: str | os.PathLike, overwrite: bool = False) -> str:
        """Write the capture to HDF5 (atomically); returns the path.

        Raises ``FileExistsError`` when ``path`` exists and ``overwrite`` is False.
        """
        import h5py

        path = os.fspath(path)
        if os.path.exists(path) and not overwrite:
            raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
        with atomic_path(path, suffix=".h5.part") as tmp:
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
        """Read a capture written by :meth:`save`."""
        import h5py

        path = os.fspath(path)
        try:
            f = h5py.File(path, "r")
        except OSError as e:
            raise CaptureFormatError(f"{path}: not a readable HDF5 file ({e})") from None
        with f:
            if f.attrs.get("format") != FORMAT_NAME:
                raise CaptureFormatError(f"{path}: HDF5 file is not a sionna_mmir capture "
                                         f"(attribute 'format' is {f.attrs.get('format')!r})")
            version = int(f.attrs.get("version", -1))
            if version > FORMAT_VERSION:
                raise CaptureFormatError(f"{path}: capture format version {version} is newer "
                                         f"than this sionna_mmir ({FORMAT_VERSION})")
            for key in ("radar", "metadata"):
                if key not in f.attrs:
                    raise CaptureFormatError(f"{path}: missing attribute {key!r}")
            if "adc" not in f:
                raise CaptureFormatError(f"{path}: missing dataset 'adc'")
            try:
                radar = RadarConfig.from_dict(json.loads(f.attrs["radar"]))
                metadata = json.loads(f.attrs["metadata"])
            except json.JSONDecodeError as e:
                raise CaptureFormatError(f"{path}: corrupt JSON attribute ({e})") from None
            try:
                adc = f["adc"][()]
            except OSError as e:  # truncated file
                raise CaptureFormatError(f"{path}: cannot read 'adc' (truncated?): {e}") from None
            extras = {k: v[()] for k, v in f["extras"].items()} if "extras" in f else {}
            source = str(f.attrs.get("source", path))
        return cls(adc, radar, metadata, source, extras)
