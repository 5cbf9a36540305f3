"""Single-frame 3-D occupancy: render a dense array, RAE cube, points, metrics.

:func:`occupancy` chains the stages of the paper's dense-aperture
experiment::

    scene --render (single bounce)--> ADC [tx, rx, 1, sample]
          --rae_cube--> power [range, azimuth, elevation]
          --99.9th percentile--> point cloud (scene frame)
    clean mesh --sample, line of sight, beam, voxel grid, intensity gate--> reference
    point cloud vs reference --cKDTree, tau = 0.5 m--> metrics

:func:`extruded_baseline` gives the near-1-D cascade's counterpart (its RA map
extruded over its elevation beam), scored by :func:`score` against the same
reference.  Render defaults (:data:`DENSE_RENDER`): single bounce
(``max_depth=1``, as the paper at test time), deterministic per-facet
quadrature (``sampling="facets"``) and paths pruned 50 dB under the strongest
(``min_rel_power=1e-5``), no diffraction; the dense frame's ADC by the
block-pair spread (:mod:`sionna_mmir.fmcw.synthesize_blocks`).
"""
from __future__ import annotations

import contextlib
import os
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputValueError
from ..processing.rae import (RAECube, bin_directions, check_elevation_aperture, elevation_bins,
                              extruded_cube, range_azimuth_map, rae_cube)
from .gating import (DEFAULT_MIN_INTENSITY, DEFAULT_POINTS_PER_M2, ReferenceSet, beam_mask,
                     check_overlap, read_meshes, reference_points)
from .metrics import DEFAULT_TAU, occupancy_metrics
from .point_cloud import (DEFAULT_DYNAMIC_RANGE_DB, DEFAULT_PERCENTILE, PointCloud,
                          extract_point_cloud)

#: Solver options of the dense-array render (module docstring).
DENSE_RENDER = {"max_depth": 1, "sampling": "facets", "min_rel_power": 1e-5, "seed": 0}
#: ADC synthesis choices of :func:`render_adc`
SYNTHESES = ("exact", "blocks")


@dataclass
class OccupancyResult:
    """Outcome of :func:`occupancy`.

    Attributes
    ----------
    cube : RAECube
        The dense array's cube, shape (n_range, n_azimuth, n_elevation).
    cloud : PointCloud
        Radar points, scene frame [m].
    reference : ReferenceSet
        Gated points of the clean mesh, scene frame [m].
    metrics : dict
        :func:`~.metrics.occupancy_metrics` of ``cloud`` against ``reference``.
    radar : RadarConfig
        The posed dense radar.
    timings : dict
        ``render_s`` (paths + ADC), ``rae_s``, ``frame_s`` (their sum),
        ``reference_s``, ``metrics_s`` [s].
    settings : dict
        The options used.
    """

    cube: RAECube
    cloud: PointCloud
    reference: ReferenceSet
    metrics: dict
    radar: object
    timings: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)


def _label(x) -> str:
    """A path (or paths) naming ``x`` in error messages, else a description."""
    if isinstance(x, (str, os.PathLike)):
        return os.fspath(x)
    if isinstance(x, dict) and x and all(isinstance(v, (str, os.PathLike)) for v in x.values()):
        return ", ".join(os.fspath(v) for v in x.values())
    return type(x).__name__


@contextlib.contextmanager
def _prefixed(label: str):
    """Re-raise :class:`InputValueError` with ``label: `` in front."""
    try:
        yield
    except InputValueError as exc:
        raise InputValueError(f"{label}: {exc}") from exc


def posed(radar, pose=None):
    """``radar`` moved to ``pose = (position (3,) [m], orientation (3,) [rad])``; as is if None."""
    if pose is None:
        return radar
    position, orientation = pose
    return radar.replace(position=np.asarray(position, float),
                         orientation=np.asarray(orientation, float))


def as_scene(scene, materials: dict | None = None):
    """A :class:`~sionna_mmir.scene.RadarScene`; meshes (path / dict) go through ``load_scene``."""
    from ..scene import RadarScene, load_scene

    return scene if isinstance(scene, RadarScene) else load_scene(scene, materials=materials)


def render_adc(scene, radar, render_options: dict | None = None, source: str = "scene",
               synthesis: str = "exact", timings: dict | None = None):
    """One frame of ADC of ``scene`` seen by ``radar`` at its pose.

    Parameters
    ----------
    scene : RadarScene
        The scene (its pose tensors are set to ``radar``'s).
    radar : RadarConfig
        Posed radar.
    render_options : dict, optional
        :class:`~sionna_mmir.paths.RadarPathSolver` options over :data:`DENSE_RENDER`.
    source : str, optional
        Name of the scene in error messages.
    synthesis : {"exact", "blocks"}, optional
        ADC synthesis: the exact per-pair NUFFT (:mod:`sionna_mmir.fmcw.synthesize_nufft`)
        or the block-pair spread for dense arrays
        (:func:`~sionna_mmir.fmcw.synthesize_blocks.synthesize_adc_blocks`,
        ~2 % relative error, static scenes).
    timings : dict, optional
        Receives ``paths_s`` and ``adc_s`` [s].

    Returns
    -------
    ndarray of complex64, shape (n_tx, n_rx, n_chirps, n_samples)

    Raises
    ------
    InputValueError
        "empty point cloud": no ray from the radar hits the scene.
    """
    import mitsuba as mi

    from ..paths import RadarPathSolver, to_numpy

    if synthesis not in SYNTHESES:
        raise InputValueError(f"{source}: synthesis must be one of {SYNTHESES}, got {synthesis!r}")
    opts = {**DENSE_RENDER, **(render_options or {})}
    t0 = time.perf_counter()
    scene.position = mi.TensorXf(mi.Float(np.asarray(radar.position, np.float32)), (3,))
    scene.orientation = mi.TensorXf(mi.Float(np.asarray(radar.orientation, np.float32)), (3,))
    paths = RadarPathSolver()(scene, radar, **opts)
    if paths.num_paths == 0:
        raise InputValueError(f"{source}: empty point cloud: no ray from the radar at "
                              f"{np.round(radar.position, 3).tolist()} hits the scene "
                              "(check the pose and that the meshes lie in front of the radar)")
    if synthesis == "blocks" and paths.is_factorised and paths.factors.rate is None:
        from ..fmcw.synthesize_blocks import synthesize_adc_blocks

        c, g_t, tau_t, g_r, tau_r, _ = paths.factors.numpy()    # evaluates the traced paths
        t1 = time.perf_counter()
        adc = synthesize_adc_blocks(radar, c, g_t, tau_t, g_r, tau_r)
    else:
        t1 = time.perf_counter()
        adc = to_numpy(paths.adc(radar))
    if timings is not None:
        timings.update(paths_s=t1 - t0, adc_s=time.perf_counter() - t1)
    return adc


def dense_cube(scene, radar, *, render_options=None, n_azimuth: int = 127,
               n_elevation: int = 127, source: str = "scene", synthesis: str = "blocks"):
    """Render a posed 2-D array and form its RAE cube.

    Parameters
    ----------
    scene : RadarScene
    radar : RadarConfig
        Posed radar with a 2-D aperture.
    render_options, source
        As :func:`render_adc`.
    n_azimuth, n_elevation : int, optional
        Angle FFT lengths (127).
    synthesis : {"blocks", "exact"}, optional
        ADC synthesis (:func:`render_adc`; default the block-pair spread).

    Returns
    -------
    cube : RAECube
    timings : dict
        ``paths_s``, ``adc_s``, ``render_s`` (their sum), ``rae_s``, ``frame_s`` [s].
    """
    check_elevation_aperture(radar)
    timings = {}
    t0 = time.perf_counter()
    adc = render_adc(scene, radar, render_options, source, synthesis, timings)
    t1 = time.perf_counter()
    cube = rae_cube(adc, radar, n_azimuth=n_azimuth, n_elevation=n_elevation)
    t2 = time.perf_counter()
    timings.update(render_s=t1 - t0, rae_s=t2 - t1, frame_s=t2 - t0)
    return cube, timings


def extruded_baseline(scene, radar, *, render_options=None, n_azimuth: int = 127,
                      n_elevation: int = 127, pattern=None, level_db: float = 0.0,
                      source: str = "scene") -> RAECube:
    """A near-1-D array's (the cascade's) RA map extruded over its elevation beam.

    ``radar`` renders ``scene`` with the same options as the dense array; the
    RA map of its azimuth row is copied onto the elevation bins whose
    direction lies inside the elements' beam limits.

    Parameters
    ----------
    scene : RadarScene
    radar : RadarConfig
        Posed radar (e.g. ``RadarConfig.mmwcas()``).
    render_options, source
        As :func:`render_adc`.
    n_azimuth, n_elevation : int, optional
        Azimuth FFT length and number of elevation bins (127).
    pattern, level_db
        Beam limits, as :func:`~.gating.beam_mask` (0 dBi).

    Returns
    -------
    RAECube
        Shape (n_range, n_azimuth, n_elevation), ``kind="extruded"``.
    """
    adc = render_adc(scene, radar, render_options, source)
    ra, ranges, az, origin = range_azimuth_map(adc, radar, n_azimuth=n_azimuth)
    el = elevation_bins(radar, n_elevation)
    mask = beam_mask(bin_directions(az, el), pattern, level_db)
    return extruded_cube(ra, ranges, az, el, mask, origin)


def score(cube: RAECube, reference: ReferenceSet, radar, *, percentile=DEFAULT_PERCENTILE,
          dynamic_range_db=DEFAULT_DYNAMIC_RANGE_DB, tau=DEFAULT_TAU):
    """Point cloud of a cube and its metrics against a reference.

    Parameters
    ----------
    cube : RAECube
    reference : ReferenceSet
    radar : RadarConfig
        The posed radar of ``cube``.
    percentile, dynamic_range_db, tau
        As :func:`occupancy`.

    Returns
    -------
    cloud : PointCloud
    metrics : dict
    """
    cloud = extract_point_cloud(cube, radar.position, radar.orientation, percentile=percentile,
                                dynamic_range_db=dynamic_range_db)
    return cloud, occupancy_metrics(cloud.points, reference.points, tau)


def occupancy(scene, radar_dense, mesh, pose=None, *, materials: dict | None = None,
              render_options: dict | None = None, n_azimuth: int = 127, n_elevation: int = 127,
              percentile: float = DEFAULT_PERCENTILE, tau: float = DEFAULT_TAU,
              min_intensity: float = DEFAULT_MIN_INTENSITY,
              dynamic_range_db: float = DEFAULT_DYNAMIC_RANGE_DB,
              points_per_m2: float = DEFAULT_POINTS_PER_M2, seed: int = 0,
              line_of_sight: bool = True, progress: bool = False,
              source: str | None = None, synthesis: str = "blocks") -> OccupancyResult:
    """Single-frame 3-D occupancy of a (fitted) scene from a dense virtual array.

    Parameters
    ----------
    scene : RadarScene, str, trimesh.Trimesh or dict
        The scene (e.g. :func:`~sionna_mmir.fit.load_fitted_scene`), or meshes
        for :func:`~sionna_mmir.scene.load_scene` (with ``materials``).
    radar_dense : RadarConfig
        Radar with a 2-D virtual aperture, e.g. ``RadarConfig.dense(100, 100)``.
    mesh : str, trimesh.Trimesh or dict
        Clean reference mesh(es), scene frame [m].
    pose : tuple, optional
        ``(position (3,) [m], orientation (yaw, pitch, roll) (3,) [rad])``;
        default ``radar_dense``'s own.
    materials : dict, optional
        ITU material per object when ``scene`` is meshes.
    render_options : dict, optional
        Solver options over :data:`DENSE_RENDER` (single bounce).
    n_azimuth, n_elevation : int, optional
        Angle FFT lengths (127 x 127).
    percentile : float, optional
        Point-cloud threshold percentile (99.9).
    tau : float, optional
        Match threshold [m] (0.5).
    min_intensity : float, optional
        Reference gate on the normalised intensity (0.1).
    dynamic_range_db : float, optional
        Dynamic range of the normalised intensity [dB] (60).
    points_per_m2 : float, optional
        Clean-mesh sampling density [1 / m^2] (400).
    seed : int, optional
        Sampling seed of the reference points.
    line_of_sight : bool, optional
        Keep only reference points seen from the radar (True).
    progress : bool, optional
        tqdm bar over the stages.
    source : str, optional
        Name of the scene in error messages (default: its path(s)).
    synthesis : {"blocks", "exact"}, optional
        ADC synthesis of the dense frame (:func:`render_adc`).

    Returns
    -------
    OccupancyResult

    Raises
    ------
    ConfigError
        ``radar_dense`` has no elevation aperture (a 1-D array).
    InputValueError
        An unreadable mesh; a reference mesh outside the radar's view
        (mismatched frames); a scene the radar does not see (empty point cloud).
    """
    from tqdm import tqdm

    radar = posed(radar_dense, pose)
    check_elevation_aperture(radar)
    ref_meshes = read_meshes(mesh)
    with _prefixed(_label(mesh)):
        check_overlap(ref_meshes, radar)
    source = _label(scene) if source is None else source
    bar = tqdm(total=4, desc="occupancy", unit="stage", disable=not progress)
    try:
        bar.set_postfix_str("render + RAE")
        cube, timings = dense_cube(as_scene(scene, materials), radar, render_options=render_options,
                                   n_azimuth=n_azimuth, n_elevation=n_elevation, source=source,
                                   synthesis=synthesis)
        bar.update()
        bar.set_postfix_str("point cloud")
        with _prefixed(source):
            cloud = extract_point_cloud(cube, radar.position, radar.orientation,
                                        percentile=percentile, dynamic_range_db=dynamic_range_db)
        bar.update()
        bar.set_postfix_str("reference")
        t0 = time.perf_counter()
        with _prefixed(_label(mesh)):
            ref = reference_points(ref_meshes, cube, radar.position, radar.orientation,
                                   points_per_m2=points_per_m2, seed=seed,
                                   min_intensity=min_intensity, dynamic_range_db=dynamic_range_db,
                                   use_line_of_sight=line_of_sight)
        t1 = time.perf_counter()
        bar.update()
        bar.set_postfix_str("metrics")
        metrics = occupancy_metrics(cloud.points, ref.points, tau)
        timings.update(reference_s=t1 - t0, metrics_s=time.perf_counter() - t1)
        bar.update()
    finally:
        bar.close()
    settings = {"render": {**DENSE_RENDER, **(render_options or {})}, "synthesis": synthesis,
                "n_azimuth": n_azimuth,
                "n_elevation": n_elevation, "percentile": percentile, "tau": tau,
                "min_intensity": min_intensity, "dynamic_range_db": dynamic_range_db,
                "points_per_m2": points_per_m2, "seed": seed, "line_of_sight": line_of_sight}
    return OccupancyResult(cube, cloud, ref, metrics, radar, timings, settings)


def save_result(result: OccupancyResult, folder, *, overwrite: bool = False, binary: bool = True,
                title: str = "") -> dict:
    """Write ``points.ply``, ``metrics.json`` and ``occupancy.png`` into a folder.

    The files are written into ``<folder>.partial``, renamed into place at
    the end, so a failure leaves nothing at ``folder``.

    Parameters
    ----------
    result : OccupancyResult
    folder : str or os.PathLike
        Output folder.
    overwrite : bool, optional
        Replace an existing folder.
    binary : bool, optional
        Binary (default) or ASCII PLY.
    title : str, optional
        Picture title.

    Returns
    -------
    dict
        ``"ply"``, ``"metrics"``, ``"figure"`` -> path.

    Raises
    ------
    FileExistsError
        ``folder`` exists and not ``overwrite``.
    """
    import json
    import shutil

    from .plot import save_occupancy_figure
    from .ply import write_ply

    folder = os.fspath(folder)
    if os.path.exists(folder) and not overwrite:
        raise FileExistsError(f"{folder} exists; pass --overwrite to replace it")
    tmp = folder + ".partial"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    try:
        r = result.radar
        write_ply(os.path.join(tmp, "points.ply"), result.cloud.points, result.cloud.intensity,
                  binary=binary, comment=f"sionna_mmir occupancy, radar {r.name}, scene frame [m]")
        info = {"metrics": result.metrics, "reference_counts": result.reference.counts,
                "timings_s": result.timings, "settings": result.settings,
                "radar": {"name": r.name, "position_m": np.asarray(r.position).tolist(),
                          "orientation_rad": np.asarray(r.orientation).tolist()},
                "cube_shape": list(result.cube.shape)}
        with open(os.path.join(tmp, "metrics.json"), "w") as f:
            json.dump(info, f, indent=1, default=float)
        save_occupancy_figure(os.path.join(tmp, "occupancy.png"), {r.name: result.cloud},
                              result.reference.points, r.position, r.orientation, title)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if os.path.exists(folder):
        shutil.rmtree(folder)
    os.replace(tmp, folder)
    return {k: os.path.join(folder, f) for k, f in (("ply", "points.ply"),
                                                    ("metrics", "metrics.json"),
                                                    ("figure", "occupancy.png"))}
