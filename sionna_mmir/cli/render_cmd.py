"""``sionna-mmir render``: meshes + radar -> rendered raw ADC in an HDF5 capture."""
from __future__ import annotations

import os

import numpy as np

from ..errors import ConfigError, InputValueError


def _triple(text: str, what: str) -> tuple:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != 3 or not np.all(np.isfinite(vals)):
        raise InputValueError(f"{what}: expected three comma-separated numbers, got {text!r}")
    return vals


def _named(items, what, parse):
    out = {}
    for item in items or []:
        if "=" not in item:
            raise InputValueError(f"{what}: expected NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        out[name] = parse(value)
    return out


def add_parser(sub) -> None:
    p = sub.add_parser("render", help="render raw ADC of PLY/OBJ meshes into an HDF5 capture")
    p.add_argument("meshes", nargs="+", help="PLY/OBJ files; each is one object named by its "
                                             "file stem")
    p.add_argument("--output", required=True, help="output .h5 capture")
    p.add_argument("--material", action="append", metavar="OBJECT=ITU",
                   help="ITU-R P.2040 material per object (default concrete); repeatable")
    p.add_argument("--radar", default="mmwcas", choices=["mmwcas", "awr1843", "dense"])
    p.add_argument("--position", default="0,0,0", help="radar position x,y,z [m]")
    p.add_argument("--orientation", default="0,0,0", help="radar yaw,pitch,roll [deg]")
    p.add_argument("--chirps", type=int, default=None, help="chirp loops per frame")
    p.add_argument("--frames", type=int, default=1, help="frames (new seed each; progress bar)")
    p.add_argument("--rays", type=int, default=50_000, help="candidate rays per frame")
    p.add_argument("--depth", type=int, default=3, help="interactions per path")
    p.add_argument("--cone", type=float, default=90.0, help="ray cone half-angle [deg]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--velocity", action="append", metavar="OBJECT=VX,VY,VZ",
                   help="object velocity [m/s] (Doppler); repeatable")
    p.add_argument("--noise-db", type=float, default=None,
                   help="receiver noise power per ADC sample relative to the peak sample [dB]")
    p.add_argument("--overwrite", action="store_true")


def cmd_render(args) -> int:
    from tqdm import tqdm

    from ..captures.capture import Capture
    from ..paths import RadarPathSolver, to_numpy
    from ..scene import load_scene
    from .commands import _check_new, named_radar

    _check_new(args.output, args.overwrite)
    if args.frames < 1:
        raise ConfigError(f"--frames must be >= 1, got {args.frames}")
    names = {}
    for path in args.meshes:
        stem = os.path.splitext(os.path.basename(path))[0].replace(".", "_")
        if stem in names:
            raise InputValueError(f"{path}: two meshes share the object name {stem!r}")
        names[stem] = path
    materials = _named(args.material, "--material", str)
    velocities = _named(args.velocity, "--velocity", lambda v: _triple(v, "--velocity"))
    ori = tuple(np.radians(_triple(args.orientation, "--orientation")))
    radar = named_radar(args.radar, args.chirps,
                        position=_triple(args.position, "--position"), orientation=ori)
    scene = load_scene(names, materials=materials, radar=radar)
    solver = RadarPathSolver()
    frames = []
    hits = []
    for f in tqdm(range(args.frames), desc="render", unit="frame", disable=args.frames == 1):
        paths = solver(scene, num_rays=args.rays, max_depth=args.depth, seed=args.seed + f,
                       cone_angle_deg=args.cone, velocities=velocities or None)
        if paths.num_paths == 0:
            raise InputValueError("no ray from the radar hits the meshes: check --position / "
                                  "--orientation and that the meshes lie in front of the radar")
        hits.append(int(paths.info["hits"]))
        frames.append(to_numpy(paths.adc(radar)))
    adc = np.stack(frames)
    if args.noise_db is not None:
        rng = np.random.default_rng(args.seed)
        peak = float(np.abs(adc).max()) or 1.0
        sigma = peak * np.sqrt(10 ** (args.noise_db / 10) / 2)
        adc = adc + (sigma * (rng.standard_normal(adc.shape)
                              + 1j * rng.standard_normal(adc.shape))).astype(np.complex64)
    meta = {"meshes": names, "materials": materials, "rays": args.rays, "depth": args.depth,
            "cone_deg": args.cone, "seed": args.seed, "noise_db": args.noise_db,
            "velocities": velocities, "hits": hits}
    Capture(adc.astype(np.complex64), radar, meta, "sionna_mmir.render").save(
        args.output, overwrite=args.overwrite)
    print(f"wrote {args.output}: {adc.shape[0]} frame(s) of {adc.shape[1:]} "
          f"[tx, rx, chirp, sample], {hits[0]} ray hits in frame 0")
    return 0
