"""FMCW signal synthesis: per-path amplitudes and delays -> raw ADC."""
from .synthesize import DrAdc, synthesize_adc
from .synthesize_basic import synthesize_adc_basic

__all__ = ["DrAdc", "synthesize_adc", "synthesize_adc_basic"]
