"""Where the measured captures are: ``../shared/data/measured``.

The measured files are not redistributed; tests, the demo and the
comparison scripts find them with :func:`find_measured_dir` and skip or fall
back with a clear reason when they are absent.
"""
from __future__ import annotations

import os
import pathlib

#: the demo's default capture, relative to the measured folder
DEFAULT_CORNER_CAPTURE = pathlib.Path("mmwcas_corner") / "corner_4m7_slope79.mat"


def find_measured_dir() -> pathlib.Path | None:
    """The measured-data folder, or ``None``.

    Looks at ``$SIONNA_MMIR_MEASURED``, then ``../shared/data/measured``
    beside the working directory and beside the checkout.
    """
    env = os.environ.get("SIONNA_MMIR_MEASURED")
    candidates = [pathlib.Path(env)] if env else []
    here = pathlib.Path(__file__).resolve()
    candidates += [pathlib.Path.cwd().parent / "shared" / "data" / "measured",
                   here.parents[3] / "shared" / "data" / "measured"]
    for c in candidates:
        if c.is_dir():
            return c
    return None
