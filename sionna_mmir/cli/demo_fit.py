"""The demo's inverse-rendering stage: fit a corner-reflector scene, mmIR vs Sionna RT.

The scene is built from what the capture shows: a triangular trihedral
(edge ``CORNER_EDGE_M``, an assumption: a typical 10-15 cm lab reflector)
at the detected corner range and azimuth, its symmetry axis towards the
radar, and a floor ``FLOOR_DEPTH_M`` below the radar (an assumption: the room
is not described in the data).  Both models start from ITU metal (corner) and
concrete (floor) and are fitted to the measured RA map with the same loss,
Adam settings and iteration budget; mmIR samples a cone about boresight that
covers the corner, Sionna RT its own sphere with many samples per source.
"""
from __future__ import annotations

import numpy as np

CORNER_EDGE_M = 0.12
FLOOR_DEPTH_M = 1.0


def corner_scene_meshes(range_m: float, azimuth_rad: float, origin) -> dict:
    """``{"corner": trihedral, "floor": plane}`` in the radar frame (m)."""
    import trimesh

    a = CORNER_EDGE_M
    V = np.array([[0, 0, 0], [a, 0, 0], [0, a, 0], [0, 0, a]], float)
    faces = [trimesh.Trimesh(V, [f], process=False).subdivide().subdivide()
             for f in ([0, 1, 2], [0, 2, 3], [0, 3, 1])]
    tri = trimesh.util.concatenate(faces)
    # rotate the symmetry axis (1,1,1)/sqrt3 onto the direction towards the radar
    axis = np.ones(3) / np.sqrt(3)
    to_radar = -np.array([np.cos(azimuth_rad), np.sin(azimuth_rad), 0.0])
    v = np.cross(axis, to_radar)
    c = float(np.dot(axis, to_radar))
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    R = np.eye(3) + vx + vx @ vx / (1 + c)
    tri.vertices = tri.vertices @ R.T
    # the triple-bounce phase centre is the apex (the point farthest from the radar)
    apex = np.asarray(origin) + range_m * -to_radar
    tri.vertices += apex - tri.vertices[np.argmax(tri.vertices @ -to_radar)]
    floor = trimesh.Trimesh(np.array([[1.0, -3, -FLOOR_DEPTH_M], [8, -3, -FLOOR_DEPTH_M],
                                      [8, 3, -FLOOR_DEPTH_M], [1.0, 3, -FLOOR_DEPTH_M]]),
                            [[0, 1, 2], [0, 2, 3]], process=False)
    for _ in range(5):
        floor = floor.subdivide()
    return {"corner": tri, "floor": floor}


def fit_stage(cap, ra_meas, r_corner, az_corner, origin, *, iterations=8, rays=6000,
              sionna_samples=200_000, progress=True) -> dict:
    from ..baseline import SionnaBaseline
    from ..compare.harness import run_sides
    from ..fit import MMIRModel, SionnaModel
    from ..scene import load_scene

    radar = cap.radar
    meshes = corner_scene_meshes(r_corner, az_corner, origin)
    mats = {"corner": "metal", "floor": "concrete"}
    cone = float(np.degrees(abs(az_corner))) + 6.0
    mm = MMIRModel(load_scene(meshes, materials=mats, radar=radar),
                   solver_options=dict(num_rays=rays, max_depth=3, cone_angle_deg=min(cone, 90.0)))
    sio = SionnaModel(SionnaBaseline(meshes, mats, radar, max_depth=3,
                                     samples_per_src=sionna_samples))
    return run_sides((("mmIR", mm), ("Sionna RT", sio)), ra_meas, cap.adc,
                     iterations=iterations, lr=0.05, progress=progress)
