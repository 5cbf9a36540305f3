"""A corner-reflector scene built from what a capture shows, and its fit.

Where no mesh exists (a corner reflector in an unknown room), the scene is a
triangular trihedral (edge :data:`CORNER_EDGE_M`, an assumption: a typical
10-15 cm lab reflector) at the detected corner range and azimuth, its
symmetry axis towards the radar, and a floor :data:`FLOOR_DEPTH_M` below the
radar (an assumption: the room is not described in the data).  Both models
start from ITU metal (corner) and concrete (floor) and are fitted with the
same loss, Adam settings and iteration budget; mmIR samples a cone about
boresight that covers the corner, Sionna RT its own sphere.
"""
from __future__ import annotations

import numpy as np

from ..paths.options import SolverOptions

#: edge of the assumed trihedral [m]
CORNER_EDGE_M = 0.12
#: depth of the assumed floor below the radar [m]
FLOOR_DEPTH_M = 1.0
#: materials the corner scene starts from
CORNER_MATERIALS = {"corner": "metal", "floor": "concrete"}


def _towards(axis, target):
    """Rotation matrix taking unit ``axis`` onto unit ``target`` (Rodrigues)."""
    v = np.cross(axis, target)
    c = float(np.dot(axis, target))
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def corner_scene_meshes(range_m: float, azimuth_rad: float, origin) -> dict:
    """``{"corner": trihedral, "floor": plane}`` in the radar frame.

    Parameters
    ----------
    range_m : float
        Range of the trihedral's apex from ``origin`` [m].
    azimuth_rad : float
        Azimuth of the apex [rad].
    origin : array_like
        Radar-frame point the range is measured from [m].

    Returns
    -------
    dict
        Name -> ``trimesh.Trimesh``.
    """
    import trimesh

    a = CORNER_EDGE_M
    V = np.array([[0, 0, 0], [a, 0, 0], [0, a, 0], [0, 0, a]], float)
    faces = [trimesh.Trimesh(V, [f], process=False).subdivide().subdivide()
             for f in ([0, 1, 2], [0, 2, 3], [0, 3, 1])]
    tri = trimesh.util.concatenate(faces)
    # rotate the symmetry axis (1,1,1)/sqrt3 onto the direction towards the radar
    to_radar = -np.array([np.cos(azimuth_rad), np.sin(azimuth_rad), 0.0])
    tri.vertices = tri.vertices @ _towards(np.ones(3) / np.sqrt(3), to_radar).T
    # the triple-bounce phase centre is the apex (the point farthest from the radar)
    apex = np.asarray(origin) + range_m * -to_radar
    tri.vertices += apex - tri.vertices[np.argmax(tri.vertices @ -to_radar)]
    floor = trimesh.Trimesh(np.array([[1.0, -3, -FLOOR_DEPTH_M], [8, -3, -FLOOR_DEPTH_M],
                                      [8, 3, -FLOOR_DEPTH_M], [1.0, 3, -FLOOR_DEPTH_M]]),
                            [[0, 1, 2], [0, 2, 3]], process=False)
    for _ in range(5):
        floor = floor.subdivide()
    return {"corner": tri, "floor": floor}


def corner_cone_deg(azimuth_rad: float) -> float:
    """Ray-cone half-angle [deg] that covers a corner at ``azimuth_rad``."""
    return min(float(np.degrees(abs(azimuth_rad))) + 6.0, 90.0)


def fit_corner_scene(cap, ra_meas, r_corner, az_corner, origin, *, iterations=8, rays=6000,
                     sionna_samples=200_000, progress=True, sensor_profile=None,
                     arrival=None) -> dict:
    """Fit the corner scene with mmIR and the Sionna RT baseline, like for like.

    ``sensor_profile`` (a :class:`~sionna_mmir.effects.profile.SensorProfile`)
    is applied frozen to both models' renders (:class:`~sionna_mmir.fit.profiled.ProfiledModel`),
    with the scene's Rx-side ``arrival`` ramp when given.

    Returns the :func:`~sionna_mmir.compare.harness.run_sides` results
    (``{"mmIR": SideResult, "Sionna RT": SideResult}``).
    """
    from ..baseline import SionnaBaseline
    from ..fit import MMIRModel, SionnaModel
    from ..scene import load_scene
    from .harness import run_sides

    radar = cap.radar
    meshes = corner_scene_meshes(r_corner, az_corner, origin)
    options = SolverOptions(num_rays=rays, max_depth=3, cone_angle_deg=corner_cone_deg(az_corner))
    mm = MMIRModel(load_scene(meshes, materials=CORNER_MATERIALS, radar=radar),
                   solver_options=options.replace(min_rel_power=1e-6))
    sio = SionnaModel(SionnaBaseline(meshes, CORNER_MATERIALS, radar, max_depth=3,
                                     samples_per_src=sionna_samples))
    if sensor_profile is not None:
        from ..fit.profiled import ProfiledModel

        mm, sio = (ProfiledModel(m, sensor_profile, cap.adc, arrival=arrival) for m in (mm, sio))
    return run_sides((("mmIR", mm), ("Sionna RT", sio)), ra_meas, cap.adc,
                     iterations=iterations, lr=0.05, progress=progress)
