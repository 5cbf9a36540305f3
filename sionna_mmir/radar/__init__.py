"""Radar devices: waveform, antenna layouts, pose (cf. Sionna's ``radio_devices``)."""
from .config import SPEED_OF_LIGHT, RadarConfig, rotation_matrix

__all__ = ["RadarConfig", "SPEED_OF_LIGHT", "rotation_matrix"]
