"""The effects library: one effect per module; :data:`LIBRARY` maps names to classes."""
from .channel_gain import ChannelGain
from .dc_offset import DCOffset

LIBRARY = {cls.name: cls for cls in (ChannelGain, DCOffset)}


def default_library() -> list:
    """One instance of every library effect."""
    return [cls() for cls in LIBRARY.values()]
