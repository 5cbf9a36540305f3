"""Shared arguments of the ``sionna-mmir`` commands and their parsing.

Conventions: every output is ``--out PATH`` (a file or a report folder) and
is never replaced without ``--overwrite``; solver settings take their
defaults from a :class:`~sionna_mmir.paths.SolverOptions` preset and scaffold
settings from a :class:`~sionna_mmir.scaffold.ScaffoldOptions` preset, so a
default lives in one place; angles on the command line are degrees.
"""
from __future__ import annotations

import argparse
import contextlib
import os

import numpy as np

from ..errors import ConfigError, InputValueError
from ..paths.options import SolverOptions
from ..scaffold.prepare import SHADINGS, ScaffoldOptions

class DefaultsFormatter(argparse.HelpFormatter):
    """Help text with each meaningful default shown (not ``None`` or ``False``)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if ("%(default)" not in text and default is not None and default is not False
                and default != argparse.SUPPRESS and action.option_strings):
            text += " (default: %(default)s)"
        return text


FORMATTER = DefaultsFormatter


def add_capture(p, frame: bool = True) -> None:
    """``capture`` positional with ``--frame``, ``--calib-dir``, ``--sensor``."""
    p.add_argument("capture", help="capture: TI .mat, DCA1000 .bin, ColoRadar run folder or "
                                    "frame_N.bin, OpenRadar .npy, or sionna_mmir HDF5")
    if frame:
        p.add_argument("--frame", type=int, default=None,
                       help="frame index (multi-frame captures; default: the first)")
    p.add_argument("--calib-dir", default=None,
                   help="ColoRadar calib folder (default: found beside the run)")
    p.add_argument("--sensor", default="cascade", choices=["cascade", "single_chip"],
                   help="ColoRadar sensor")
    add_waveform(p)


def add_waveform(p) -> None:
    """``--sample-rate``, ``--slope`` and ``--waveform-config``: waveform values a
    capture file lacks (older TI calibration files)."""
    p.add_argument("--sample-rate", type=float, default=None, metavar="SPS",
                   help="ADC sample rate [samples/s] where the capture file lacks it")
    p.add_argument("--slope", type=float, default=None, metavar="MHZ_PER_US",
                   help="chirp slope [MHz/us] where the capture file lacks it")
    p.add_argument("--waveform-config", default=None, metavar="FILE",
                   help="'key value' file with sample_rate / adc_sample_frequency [sps] and "
                        "slope_mhz_per_us [MHz/us] / frequency_slope [Hz/s]")


def waveform(args) -> dict:
    """The ``load_capture(waveform=...)`` values of :func:`add_waveform`'s arguments
    (the command line wins over the config file)."""
    from ..captures.loader import read_waveform_config

    out = {}
    if getattr(args, "waveform_config", None):
        out.update(read_waveform_config(args.waveform_config))
    for flag, key, factor in (("sample_rate", "sample_rate", 1.0), ("slope", "slope", 1e12)):
        v = getattr(args, flag, None)
        if v is not None:
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"--{flag.replace('_', '-')} {v}: expected a positive number")
            out[key] = float(v) * factor
    return out


def add_sensor_profile(p) -> None:
    """``--sensor-profile PROFILE.h5``: a unit's calibrated effects, applied frozen."""
    p.add_argument("--sensor-profile", default=None, metavar="PROFILE.h5",
                   help="sensor profile of the radar unit (sionna-mmir calibrate), applied "
                        "frozen to the forward model")


def add_workers(p) -> None:
    """``--workers N|auto``: processes for the independent fits of a diagnosis round."""
    p.add_argument("--workers", default="auto",
                   help="processes for the independent fits of a diagnosis round: a number, or "
                        "'auto' for one per core; 1 runs them all in this process. "
                        "The result does not depend on it")


def add_out(p, what: str, required: bool = True, default=None, kind: str = "file") -> None:
    """``--out`` and ``--overwrite``; ``kind`` is ``"file"`` or ``"folder"``
    (checked, and a folder locked, by :func:`output_guard`)."""
    p.add_argument("--out", required=required, default=default, help=what)
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.set_defaults(_out_kind=kind)


@contextlib.contextmanager
def output_guard(args):
    """Check ``--out`` before the command works, and hold a report folder's lock.

    A file output must be new (or ``--overwrite``), have a name the file
    system allows and lie in a writable folder; a folder output the same,
    and it must not be a file.  ``--resume`` counts as ``--overwrite``.  A
    report folder is locked (``<out>.lock``) while the command runs.
    """
    from ..utils.outputs import check_output_file, check_output_folder, folder_lock

    out, kind = getattr(args, "out", None), getattr(args, "_out_kind", None)
    if not out or kind is None:
        yield
        return
    replace = bool(getattr(args, "overwrite", False) or getattr(args, "resume", False))
    if kind == "file":
        check_output_file(out, replace)
        yield
        return
    check_output_folder(out, replace)
    with folder_lock(out):
        check_output_folder(out, replace)           # as it is now the lock is held
        try:
            yield
        except OSError as exc:
            raise _about_folder(exc, out) from exc


def _about_folder(exc: OSError, out: str) -> OSError:
    """``exc`` re-made to name the report folder ``out`` when it names a file
    of its work folder (``<out>.partial``, or the demo's ``.demo-*``)."""
    if exc.filename is None or exc.errno is None:
        return exc
    path, parent = os.path.abspath(os.fsdecode(exc.filename)), os.path.dirname(os.path.abspath(out))
    first = os.path.relpath(path, parent).split(os.sep)[0]
    base = os.path.basename(os.path.abspath(out))
    if first not in (base, base + ".partial") and not first.startswith(".demo-"):
        return exc
    inner = os.path.relpath(path, os.path.join(parent, first))
    where = "" if inner == "." else f" (writing {inner})"
    return OSError(exc.errno, f"{exc.strerror or exc}{where}", out)


def add_pose(p) -> None:
    """Radar ``--position`` and ``--orientation``."""
    p.add_argument("--position", default="0,0,0", help="radar position x,y,z [m] in the scene")
    p.add_argument("--orientation", default="0,0,0",
                   help="radar yaw,pitch,roll [deg] (Sionna RT's convention)")


def add_materials(p) -> None:
    """Repeatable ``--material OBJECT=ITU``."""
    p.add_argument("--material", action="append", metavar="OBJECT=ITU",
                   help="ITU-R P.2040 material per object (default concrete); repeatable")


def add_solver(p, preset: SolverOptions, fields=("rays", "depth", "sampling", "cone",
                                                 "min_rel_power", "seed")) -> None:
    """Solver options with the preset's defaults."""
    spec = {
        "rays": ("--rays", dict(type=int, default=preset.num_rays,
                                help="candidate rays per render (random sampling)")),
        "depth": ("--depth", dict(type=int, default=preset.max_depth,
                                  help="interactions per path")),
        "sampling": ("--sampling", dict(default=preset.sampling, choices=["random", "facets"],
                                        help="path sampling (facets: deterministic per-facet "
                                             "quadrature)")),
        "cone": ("--cone", dict(type=float, default=preset.cone_angle_deg,
                                help="ray cone half-angle about boresight [deg]")),
        "min_rel_power": ("--min-rel-power", dict(
            type=float, default=preset.min_rel_power,
            help="drop paths weaker than this x the strongest before the ADC synthesis "
                 "(0 keeps all)")),
        "seed": ("--seed", dict(type=int, default=preset.seed, help="sample-set seed")),
        "diffraction": ("--diffraction", dict(action=argparse.BooleanOptionalAction,
                                              default=preset.diffraction,
                                              help="free-space diffraction at edges")),
        "boundary": ("--boundary", dict(action=argparse.BooleanOptionalAction,
                                        default=preset.boundary,
                                        help="visibility-boundary term of the position and "
                                             "pose gradients (needed to fit the radar pose)")),
        "stratified": ("--stratified", dict(action=argparse.BooleanOptionalAction,
                                            default=preset.stratified,
                                            help="random rays from a jittered grid")),
    }
    for name in fields:
        flag, kw = spec[name]
        p.add_argument(flag, **kw)
    p.set_defaults(_solver_preset=preset, _solver_fields=tuple(fields))


#: working memory per candidate ray [bytes]: a floor (measured about 54 B on a one-wall
#: scene; more paths and depth take more)
BYTES_PER_RAY = 48


def solver_options(args, **extra) -> SolverOptions:
    """The :class:`SolverOptions` the solver arguments describe (validated:
    the Dr.Jit limit on ``--rays``, and its memory floor against the machine's)."""
    from ..utils.memory import check_memory

    names = {"rays": "num_rays", "depth": "max_depth", "sampling": "sampling",
             "cone": "cone_angle_deg", "min_rel_power": "min_rel_power", "seed": "seed",
             "diffraction": "diffraction", "boundary": "boundary", "stratified": "stratified"}
    values = {names[f]: getattr(args, f) for f in args._solver_fields}
    options = args._solver_preset.replace(**values, **extra)
    check_memory(int(options.num_rays) * BYTES_PER_RAY, f"--rays {options.num_rays}: tracing")
    return options


def add_scaffold(p, preset: str = "none") -> None:
    """``--scaffold`` preset and a ``--shading`` override."""
    p.add_argument("--scaffold", default=preset, choices=["none", "lidar"],
                   help="mesh repair before fitting: none (meshes as given) or lidar "
                        "(denoise, snap planes, shading per object)")
    p.add_argument("--shading", default=None, choices=list(SHADINGS),
                   help="override the preset's shading normals")


def scaffold_options(args) -> ScaffoldOptions:
    """The :class:`ScaffoldOptions` the scaffold arguments describe."""
    opts = ScaffoldOptions.lidar() if args.scaffold == "lidar" else ScaffoldOptions.none()
    if args.shading is not None:
        opts = ScaffoldOptions(opts.denoise, opts.planes, args.shading)
    return opts


def triple(text: str, what: str) -> tuple:
    """Three finite comma-separated numbers."""
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != 3 or not np.all(np.isfinite(vals)):
        raise InputValueError(f"{what}: expected three comma-separated numbers, got {text!r}")
    return vals


def named(items, what: str, parse) -> dict:
    """``NAME=VALUE`` items -> dict, values parsed by ``parse``."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise InputValueError(f"{what}: expected NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        out[name] = parse(value)
    return out


def pose(args) -> tuple:
    """``(position [m], orientation [rad])`` of ``--position`` / ``--orientation``."""
    return (triple(args.position, "--position"),
            tuple(np.radians(triple(args.orientation, "--orientation"))))


def mesh_names(paths) -> dict:
    """Object name (file stem) -> path; two files with one stem is an error."""
    names = {}
    for path in paths:
        stem = os.path.splitext(os.path.basename(path))[0].replace(".", "_")
        try:
            stem.encode("utf-8")
        except UnicodeEncodeError:
            raise InputValueError(f"{path}: the file name is not valid UTF-8, so it cannot "
                                  "name a scene object; rename the file") from None
        if stem in names:
            raise InputValueError(f"{path}: two meshes share the object name {stem!r}")
        names[stem] = path
    return names


def speed(vals, what: str):
    """``vals`` (a velocity vector or a radial speed [m/s]) if slower than light."""
    from ..radar.config import SPEED_OF_LIGHT

    if float(np.linalg.norm(vals)) >= SPEED_OF_LIGHT:
        raise InputValueError(f"{what}: speed {float(np.linalg.norm(vals)):.6g} m/s is not "
                              f"below the speed of light ({SPEED_OF_LIGHT:.0f} m/s)")
    return vals


def noise_db(value, flag: str = "--noise-db"):
    """``value`` if it is None or a finite power ratio within +-300 dB."""
    if value is not None and not (np.isfinite(value) and abs(value) <= 300):
        raise ConfigError(f"{flag} {value}: expected a finite number of dB within +-300")
    return value


def positive(value, flag: str, minimum: int = 1) -> None:
    """Raise ``ConfigError`` unless ``value >= minimum``."""
    if value < minimum:
        raise ConfigError(f"{flag} must be >= {minimum}, got {value}")
