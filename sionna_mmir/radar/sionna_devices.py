"""Sionna RT radio devices <-> :class:`~sionna_mmir.radar.config.RadarConfig`.

A Sionna ``Transmitter`` gives the radar pose: its ``position`` [m] and
``orientation`` ``(yaw, pitch, roll)`` [rad] are the radar's (both packages
use ``R = Rz(yaw) Ry(pitch) Rx(roll)`` and antennas facing the local ``+x``).
Sionna arrays lie in the local ``y-z`` plane, which is the radar frame's
aperture plane (``+y`` left, ``+z`` up), so ``scene.tx_array`` /
``scene.rx_array`` element positions carry over unchanged once their
wavelength-normalised positions are scaled by the radar's ``lambda`` at
``design_frequency`` (Sionna scales by the Sionna scene's wavelength, 3.5 GHz
by default, which is meaningless for the radar).  Dual-polarised Sionna
antennas count once.  A ``Receiver`` at another position than the transmitter
shifts the Rx elements by the offset, expressed in the radar frame; it must
have the transmitter's orientation.

What Sionna has no notion of -- the FMCW waveform, TDM order -- comes from
``base`` (a preset name or a ``RadarConfig``).
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from .config import RadarConfig, rotation_matrix

PRESETS = ("mmwcas", "awr1843", "dense")


def preset_radar(name: str, **kw) -> RadarConfig:
    """``RadarConfig`` of a preset name (``mmwcas`` | ``awr1843`` | ``dense``)."""
    if name not in PRESETS:
        raise ConfigError(f"unknown radar preset {name!r}; choose one of {list(PRESETS)}")
    return getattr(RadarConfig, name)(**kw)


def _vec3(v) -> np.ndarray:
    return np.asarray(v, dtype=np.float64).reshape(3)


def _device(devices: dict, name, kind: str):
    if name is not None:
        if name not in devices:
            raise ConfigError(f"radar_from_sionna: no {kind} named {name!r} "
                              f"(the scene has {sorted(devices)})")
        return devices[name]
    if len(devices) > 1:
        raise ConfigError(f"radar_from_sionna: the scene has {len(devices)} {kind}s "
                          f"{sorted(devices)}; name one with {kind}=")
    return next(iter(devices.values()), None)


def _array_positions(array, wavelength: float) -> np.ndarray:
    """``[n, 3]`` element positions [m] (distinct positions, array order)."""
    pos = np.array(array.normalized_positions, dtype=np.float64).reshape(3, -1).T * wavelength
    _, first = np.unique(np.round(pos, 12), axis=0, return_index=True)
    return pos[np.sort(first)]


def radar_from_sionna(scene, base="mmwcas", transmitter: str | None = None,
                      receiver: str | None = None, use_arrays: bool = True) -> RadarConfig:
    """A ``RadarConfig`` posed at a Sionna scene's transmitter.

    Parameters
    ----------
    scene : sionna.rt.Scene
        a scene with at least one ``Transmitter``
    base : str or RadarConfig, optional
        preset name or ``RadarConfig``: waveform (and layout when
        the scene has no arrays or ``use_arrays`` is False)
    transmitter : str, optional
        name of the transmitter (default: the only one)
    receiver : str, optional
        name of the receiver (default: the only one, or none:
        co-located with the transmitter)
    use_arrays : bool, optional
        take the layout from ``scene.tx_array`` / ``rx_array``
        when both are set

    Returns
    -------
    RadarConfig
        the radar (``position`` [m], ``orientation``
        [rad] from the transmitter; provenance in ``notes``)

    Raises
    ------
    ConfigError
        The scene has no (or an ambiguous) transmitter, or a receiver
        oriented differently from it.
    """
    radar = preset_radar(base) if isinstance(base, str) else base
    if not isinstance(radar, RadarConfig):
        raise ConfigError(f"radar_from_sionna: base must be a preset name or RadarConfig, "
                          f"got {type(base).__name__}")
    tx = _device(dict(scene.transmitters), transmitter, "transmitter")
    if tx is None:
        raise ConfigError("radar_from_sionna: the Sionna scene has no Transmitter")
    rx = _device(dict(scene.receivers), receiver, "receiver")
    position, orientation = _vec3(tx.position), _vec3(tx.orientation)
    notes = list(radar.notes) + [f"pose from Sionna transmitter {tx.name!r}"]
    changes = dict(position=position, orientation=orientation)
    offset = np.zeros(3)
    if rx is not None:
        if not np.allclose(_vec3(rx.orientation), orientation, atol=1e-6):
            raise ConfigError(f"radar_from_sionna: receiver {rx.name!r} is oriented "
                              f"{_vec3(rx.orientation).tolist()}, the transmitter "
                              f"{orientation.tolist()}; a radar needs one orientation")
        offset = rotation_matrix(orientation).T @ (_vec3(rx.position) - position)
        notes.append(f"Rx shifted by Sionna receiver {rx.name!r} at {offset.tolist()} m")
    if use_arrays and scene.tx_array is not None and scene.rx_array is not None:
        lam = 2.0 * radar.half_wavelength
        changes.update(tx_positions=_array_positions(scene.tx_array, lam),
                       rx_positions=_array_positions(scene.rx_array, lam) + offset,
                       tdm_order=None)
        notes.append(f"layout from Sionna tx_array/rx_array at {radar.design_frequency:g} Hz")
    else:
        changes["rx_positions"] = radar.rx_positions + offset
    return radar.replace(notes=tuple(notes), **changes)


def radar_to_sionna(radar: RadarConfig, scene=None, name: str = "radar", pattern: str = "iso"):
    """Sionna devices of a radar: ``(Transmitter, Receiver, tx_array, rx_array)``.

    Element positions are normalised by ``lambda`` at ``design_frequency``
    (the inverse of :func:`radar_from_sionna`); Sionna stores them in
    float32, so a round trip agrees to ~1e-7 relative.

    Parameters
    ----------
    radar : RadarConfig
        :class:`RadarConfig` (pose and layout)
    scene : sionna.rt.Scene, optional
        the devices are added to it and
        its ``tx_array`` / ``rx_array`` set
    name : str, optional
        device names ``<name>-tx`` / ``<name>-rx``
    pattern : str, optional
        Sionna antenna pattern name (default ``"iso"``, V-polarised)

    Returns
    -------
    tuple
        the four objects ``(Transmitter, Receiver, tx_array, rx_array)``
    """
    import mitsuba as mi
    from sionna.rt import AntennaArray, Receiver, Transmitter
    from sionna.rt.antenna_pattern import antenna_pattern_registry

    lam = 2.0 * radar.half_wavelength
    arrays = []
    for pos in (radar.tx_positions, radar.rx_positions):
        norm = np.ascontiguousarray((pos / lam).T, dtype=np.float32)
        arrays.append(AntennaArray(antenna_pattern_registry.get(pattern)(polarization="V"),
                                   mi.Point3f(norm)))
    p, o = radar.position.tolist(), radar.orientation.tolist()
    tx = Transmitter(f"{name}-tx", position=mi.Point3f(p), orientation=mi.Point3f(o))
    rx = Receiver(f"{name}-rx", position=mi.Point3f(p), orientation=mi.Point3f(o))
    if scene is not None:
        scene.add(tx)
        scene.add(rx)
        scene.tx_array, scene.rx_array = arrays
    return tx, rx, arrays[0], arrays[1]
