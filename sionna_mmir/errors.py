"""Exceptions raised on bad input.

Every error names the offending file or argument and what is wrong with it, so
that the command line can print it as is and exit non-zero.
"""


class SionnaMMIRError(ValueError):
    """Base class of all input errors raised by sionna_mmir."""


class ConfigError(SionnaMMIRError):
    """A radar configuration is missing keys, has wrong keys or bad values."""


class CaptureFormatError(SionnaMMIRError):
    """A capture file is truncated, mis-sized or not of the expected layout."""


class InputValueError(SionnaMMIRError):
    """An array argument has the wrong shape or holds NaN / Inf."""


class FrameIndexError(SionnaMMIRError, IndexError):
    """A frame index outside the capture (also an ``IndexError``)."""


class ResourceError(SionnaMMIRError):
    """A request larger than the machine: the memory it needs, or a Dr.Jit limit."""


class OutputError(SionnaMMIRError):
    """An output path that cannot be used: not a folder, name too long, in use."""
