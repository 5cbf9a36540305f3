"""Reference points from the clean mesh, gated by what the radar can see.

The paper evaluates against LiDAR points after radar-guided filtering:
(1) the dense array's 0 dB beam limits, (2) projection onto the radar's
polar voxel grid, (3) radar normalised intensity >= 0.1.  Here the points
are sampled on the clean mesh instead of a LiDAR frame:

0. **Sampling** -- ``points_per_m2`` points per square metre, area-weighted
   over all triangles (triangle drawn with probability proportional to its
   area, uniform barycentric point in it), NumPy generator with a fixed
   ``seed``.
1. **Line of sight** (optional, on by default) -- the segment from the
   aperture's phase centre to the point must not hit the mesh (Mitsuba ray
   test, 2 mm short of the point), as for a LiDAR frame taken at the radar.
2. **0 dB beam limits** -- the direction ``u`` of the point seen from the
   phase centre (radar frame) must have an element power gain ``G(u) >= 1``
   (0 dBi) for the element pattern of the renderer (default
   :class:`~sionna_mmir.radio_devices.CosinePowerPattern`:
   ``G = 10.83 cos(az)^2 cos(el)^10``, i.e. the region bounded by
   ``|az| <= 72.3 deg`` on the horizon and ``|el| <= 38.0 deg`` on boresight).
3. **Polar voxel grid** -- the point's range, ``u_y`` and ``u_z`` must fall
   inside the cube's bins (nearest bin centre, half a bin beyond the first and
   last centres).
4. **Intensity** -- the normalised intensity
   (:func:`~.point_cloud.normalised_intensity`, log scale over 60 dB) of
   that voxel must be ``>= min_intensity`` (0.1).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputValueError
from ..processing.rae import RAECube
from ..radar.config import rotation_matrix
from .point_cloud import DEFAULT_DYNAMIC_RANGE_DB, normalised_intensity, scene_to_radar

#: Default sampling density of the clean mesh [points / m^2] (~5 cm spacing).
DEFAULT_POINTS_PER_M2 = 400.0
#: Default intensity gate (the paper's 0.1).
DEFAULT_MIN_INTENSITY = 0.1
#: The segment test stops this short of the sampled point [m].
LOS_MARGIN_M = 2e-3


@dataclass
class ReferenceSet:
    """Gated reference points.

    Attributes
    ----------
    points : ndarray of float64, shape (n, 3)
        Scene-frame points [m].
    counts : dict
        Stage -> points left after it: ``sampled``, ``line_of_sight``,
        ``beam``, ``grid``, ``intensity``.
    """

    points: np.ndarray
    counts: dict = field(default_factory=dict)


def read_meshes(meshes) -> list:
    """Read and validate meshes.

    Parameters
    ----------
    meshes : str, os.PathLike, trimesh.Trimesh or dict
        A PLY/OBJ path, a mesh, or ``dict`` name -> either (scene frame, m).

    Returns
    -------
    list of TriMeshData

    Raises
    ------
    InputValueError
        An unreadable or empty mesh (naming the file).
    """
    from ..scene.mesh_io import read_mesh

    items = meshes.items() if isinstance(meshes, dict) else [(None, meshes)]
    return [read_mesh(m, source=None if name is None or not hasattr(m, "faces")
                      else f"mesh {name!r}", drop_degenerate=True) for name, m in items]


def sample_surface(meshes, points_per_m2: float = DEFAULT_POINTS_PER_M2,
                   seed: int = 0) -> np.ndarray:
    """Area-weighted uniform points on triangle meshes.

    Parameters
    ----------
    meshes : list of TriMeshData
        From :func:`read_meshes`.
    points_per_m2 : float, optional
        Density [1 / m^2]; ``n = round(points_per_m2 * total area)`` (>= 1).
    seed : int, optional
        Seed of the NumPy generator.

    Returns
    -------
    ndarray of float64, shape (n, 3)
        Points [m].
    """
    if not (np.isfinite(points_per_m2) and points_per_m2 > 0):
        raise InputValueError(f"points_per_m2 must be positive, got {points_per_m2!r}")
    tris = np.concatenate([m.vertices[m.faces] for m in meshes])           # [F, 3, 3]
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]),
                                axis=1)
    n = max(1, int(round(points_per_m2 * area.sum())))
    rng = np.random.default_rng(seed)
    f = rng.choice(len(tris), size=n, p=area / area.sum())
    a, b = rng.random(n), rng.random(n)
    flip = a + b > 1.0
    a[flip], b[flip] = 1.0 - a[flip], 1.0 - b[flip]
    t = tris[f]
    return t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])


def line_of_sight(points, origin, meshes) -> np.ndarray:
    """Line-of-sight test (Mitsuba ``ray_test``).

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Points [m].
    origin : array_like, shape (3,)
        Viewpoint [m].
    meshes : list of TriMeshData
        Occluders.

    Returns
    -------
    ndarray of bool, shape (n,)
        True where the segment ``origin -> points[i]``, stopped
        :data:`LOS_MARGIN_M` short, misses every mesh.
    """
    from ..scene.mesh_io import to_mitsuba_mesh
    from ..utils.backend import init_backend

    init_backend()
    import mitsuba as mi

    scene = mi.load_dict({"type": "scene", **{f"m{i}": to_mitsuba_mesh(m, f"m{i}")
                                              for i, m in enumerate(meshes)}})
    d = np.asarray(points, float) - np.asarray(origin, float).reshape(1, 3)
    dist = np.linalg.norm(d, axis=1)
    d = (d / np.maximum(dist, 1e-12)[:, None]).astype(np.float32)
    o = np.broadcast_to(np.asarray(origin, np.float32).reshape(1, 3), d.shape)
    ray = mi.Ray3f(mi.Point3f(*(mi.Float(np.ascontiguousarray(o[:, k])) for k in range(3))),
                   mi.Vector3f(*(mi.Float(np.ascontiguousarray(d[:, k])) for k in range(3))))
    ray.maxt = mi.Float(np.maximum(dist - LOS_MARGIN_M, 0.0).astype(np.float32))
    return ~np.array(scene.ray_test(ray), dtype=bool)


def beam_mask(directions, pattern=None, level_db: float = 0.0) -> np.ndarray:
    """Directions inside the element's beam limits: ``G(u) >= 10^(level_db / 10)``.

    Parameters
    ----------
    directions : array_like, shape (..., 3)
        Radar-frame unit vectors (rows with NaN are outside).
    pattern : BeamPattern, optional
        Element pattern with one element (default ``CosinePowerPattern()``,
        the renderer's default).
    level_db : float, optional
        Gain limit [dBi] (0: the 0 dB beam limits).

    Returns
    -------
    ndarray of bool, shape (...)
    """
    from ..radio_devices import CosinePowerPattern

    pattern = CosinePowerPattern() if pattern is None else pattern
    d = np.asarray(directions, dtype=np.float64)
    ok = np.isfinite(d).all(axis=-1)
    flat = np.where(ok[..., None], d, [1.0, 0.0, 0.0]).reshape(-1, 3)
    g = np.asarray(pattern.gain_np(flat), dtype=np.float64).reshape(ok.shape)
    return ok & (g >= 10.0 ** (level_db / 10.0))


def _nearest_bin(values, centres):
    """Nearest index on a uniform grid and whether it is within half a bin of it."""
    c = np.asarray(centres, dtype=np.float64)
    step = (c[-1] - c[0]) / max(len(c) - 1, 1)
    i = np.rint((np.asarray(values, float) - c[0]) / step).astype(np.int64)
    ok = (i >= 0) & (i < len(c))
    return np.clip(i, 0, len(c) - 1), ok


def voxel_of(cube: RAECube, points_radar):
    """Nearest voxel of radar-frame points.

    Parameters
    ----------
    cube : RAECube
        The cube whose grid is used.
    points_radar : array_like, shape (n, 3)
        Radar-frame points [m]; ranges and direction sines are measured from
        ``cube.origin_m``.

    Returns
    -------
    index : tuple of three ndarray of int64, each shape (n,)
        ``(i_range, i_azimuth, i_elevation)`` (clipped into the grid).
    inside : ndarray of bool, shape (n,)
        Within half a bin of the grid and in front of the radar.
    """
    q = np.asarray(points_radar, float) - cube.origin_m[None, :]
    r = np.linalg.norm(q, axis=1)
    u = q / np.maximum(r, 1e-12)[:, None]
    i_r, ok_r = _nearest_bin(r, cube.ranges_m)
    i_a, ok_a = _nearest_bin(u[:, 1], np.sin(cube.azimuths_rad))
    i_e, ok_e = _nearest_bin(u[:, 2], np.sin(cube.elevations_rad))
    return (i_r, i_a, i_e), ok_r & ok_a & ok_e & (u[:, 0] > 0)


def check_overlap(meshes, radar, points_per_m2: float = 50.0, pattern=None,
                  level_db: float = 0.0) -> int:
    """Check, before rendering, that the meshes lie in the radar's view.

    Points sampled at ``points_per_m2`` (seed 0) are taken into the radar
    frame and counted if inside the beam (:func:`beam_mask`) and closer than
    ``radar.max_range``.

    Parameters
    ----------
    meshes : list of TriMeshData, or as :func:`read_meshes`
        Scene-frame meshes.
    radar : RadarConfig
        Posed radar.
    points_per_m2 : float, optional
        Sampling density [1 / m^2].
    pattern, level_db
        As :func:`beam_mask`.

    Returns
    -------
    int
        The number of points in view.

    Raises
    ------
    InputValueError
        None in view: the mesh and radar frames do not overlap.
    """
    data = meshes if isinstance(meshes, list) else read_meshes(meshes)
    q = scene_to_radar(sample_surface(data, points_per_m2, 0), radar.position, radar.orientation)
    r = np.linalg.norm(q, axis=1)
    inside = beam_mask(q / np.maximum(r, 1e-12)[:, None], pattern, level_db) & (r < radar.max_range)
    n = int(np.count_nonzero(inside))
    if n == 0:
        raise InputValueError(
            f"mesh and radar frames do not overlap: none of the {len(q)} points sampled on the "
            f"mesh lies in the radar's beam within {radar.max_range:.1f} m (radar at "
            f"{np.round(np.asarray(radar.position, float), 3).tolist()})")
    return n


def reference_points(meshes, cube: RAECube, position, orientation, *,
                     points_per_m2: float = DEFAULT_POINTS_PER_M2, seed: int = 0,
                     min_intensity: float = DEFAULT_MIN_INTENSITY,
                     dynamic_range_db: float = DEFAULT_DYNAMIC_RANGE_DB,
                     pattern=None, level_db: float = 0.0,
                     use_line_of_sight: bool = True) -> ReferenceSet:
    """Clean-mesh points the radar can see (module docstring, steps 0-4).

    Parameters
    ----------
    meshes : list of TriMeshData, or as :func:`read_meshes`
        Clean scene-frame meshes [m].
    cube : RAECube
        The dense array's cube (voxel grid and intensity gate).
    position : array_like, shape (3,)
        Radar position [m].
    orientation : array_like, shape (3,)
        Radar ``(yaw, pitch, roll)`` [rad].
    points_per_m2 : float, optional
        Sampling density [1 / m^2] (400).
    seed : int, optional
        Sampling seed.
    min_intensity : float, optional
        Gate on the voxel's normalised intensity (0.1).
    dynamic_range_db : float, optional
        Dynamic range of the normalised intensity [dB] (60).
    pattern, level_db
        Beam limits, as :func:`beam_mask` (0 dBi of the default element).
    use_line_of_sight : bool, optional
        Drop points hidden from the radar (default True).

    Returns
    -------
    ReferenceSet

    Raises
    ------
    InputValueError
        No sampled point in the beam and voxel grid (mismatched frames), an
        all-zero cube, or an unreadable mesh.
    """
    data = meshes if isinstance(meshes, list) else read_meshes(meshes)
    pts = sample_surface(data, points_per_m2, seed)
    counts = {"sampled": len(pts)}
    centre = np.asarray(position, float) + rotation_matrix(orientation) @ cube.origin_m
    if use_line_of_sight:
        pts = pts[line_of_sight(pts, centre, data)]
    counts["line_of_sight"] = len(pts)
    q = scene_to_radar(pts, position, orientation)
    rel = q - cube.origin_m[None, :]
    pts, q = _keep(pts, q, beam_mask(rel / np.maximum(np.linalg.norm(rel, axis=1), 1e-12)[:, None],
                                     pattern, level_db))
    counts["beam"] = len(pts)
    idx, inside = voxel_of(cube, q)
    pts, q, idx = pts[inside], q[inside], tuple(i[inside] for i in idx)
    counts["grid"] = len(pts)
    if len(pts) == 0:
        raise InputValueError(
            f"mesh and radar frames do not overlap: none of the {counts['sampled']} points "
            f"sampled on the mesh lies in the radar's beam and voxel grid (radar at "
            f"{np.round(np.asarray(position, float), 3).tolist()}, {counts['beam']} in the beam)")
    peak = float(cube.power[:, cube.visible].max())
    if not peak > 0:
        raise InputValueError("reference_points: the RAE cube holds no return (all zero)")
    gate = normalised_intensity(cube.power[idx], peak, dynamic_range_db) >= float(min_intensity)
    pts = pts[gate]
    counts["intensity"] = len(pts)
    return ReferenceSet(pts, counts)


def _keep(pts, q, mask):
    return pts[mask], q[mask]
