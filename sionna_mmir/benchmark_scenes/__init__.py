"""Benchmark scenes: clean geometry, ground-truth materials and LiDAR-like meshes.

Each scene exists in three forms, all generated here from code (no data files):

1. **Clean geometry** -- :func:`build_scene` (``catalog.py``): a
   :class:`SceneSpec` with one ``trimesh.Trimesh`` per object, the nominal
   ITU-R P.2040 material of each (what a user would assign; all valid at
   77 GHz), the radar pose and the LiDAR scan positions.  Used to render the
   ground-truth capture.
2. **Ground-truth materials** -- :func:`true_vertex_materials`
   (``materials.py``): spatially varying per-vertex ``[eps_real, eps_imag,
   sigma_h, l_c, tau, d]`` the fitter does not know (nominal ITU values,
   patches of other materials, weathered blobs, smooth sinusoidal variation;
   recipe in :mod:`sionna_mmir.benchmark_scenes.materials`).  Evaluate them on
   :meth:`SceneSpec.refined` meshes for rendering.
3. **LiDAR-like meshes** -- :func:`lidarize` / :func:`lidarize_scene`
   (``lidar.py``): a simulated scan (visibility by Mitsuba ray tests, range
   noise along the ray, tangential jitter) reconstructed per flat piece by
   Delaunay triangulation, with many small triangles (sub-wavelength in dense
   patches), noisy vertices, misaligned normals, holes and occlusion
   shadows.  This is what the fitter gets, with the nominal materials.
   :func:`mesh_statistics` measures it.

Common to all scenes: metres, world ``+z`` up, floor / ground at ``z = 0``;
the cascade radar at ``(0, 0, 1)``, orientation ``(0, 0, 0)`` (boresight
world ``+x``); every vertex at radar-frame ``x >= 1 m``, range <= 12 m,
azimuth within +/-60 deg (floors and grounds clipped to a +/-58 deg wedge and
an 11.9 m circle, side walls starting where the wedge meets them).  Faces
face the room / street; faces resting on the floor or against a wall are
left out; vertices are shared only inside a flat piece (vertex normals equal
face normals), except on faceted poles.  ``seed`` moves furniture, doors,
windows and cars by a few decimetres.  Defaults of :func:`lidarize`: 1 cm
spacing capped by a 200 000-triangle budget (the spacing grows to fit it:
4-6 cm on these scenes), 3 mm dense patches on 0.5 % of the visible area,
5 mm range noise, 1 % holes.

=================  ======================================================================
scene              how it is made (objects: nominal material)
=================  ======================================================================
hallway            2.4 m wide, 2.7 m high corridor from x = 1 m to an end wall at 11 m.
                   floor: concrete; ceiling: ceiling_board; side walls: plasterboard with
                   three 0.9 x 2.1 m doors recessed 8 cm (doors: wood); end wall:
                   concrete with a 1.0 x 2.2 m glass door recessed 5 cm (glass_door:
                   glass); locker 0.9 x 0.45 x 1.9 m against the left wall (metal);
                   radiator 1.0 x 0.1 x 0.6 m on the right wall (metal); bench 1.5 m on
                   two supports (wood); notice board 1.2 x 0.8 m (chipboard).
                   LiDAR from (0, 0, 1.3), (0, 0.6, 1.6), (0, -0.6, 1.0).
lab                6 m wide, 3 m high, end wall at 9 m.  floor: concrete; ceiling:
                   ceiling_board; walls: plasterboard; two 1.4 x 1.4 m windows recessed
                   15 cm in the right wall (windows: glass); a door recessed 10 cm in the
                   left wall (door: wood); three benches: 4 cm worktops (worktops: wood)
                   on cabinets (cabinets: chipboard), one glass-fronted monitor each
                   (monitors: glass); whiteboard 2.0 x 1.2 m on the end wall
                   (chipboard); locker and a 0.75 x 0.6 x 2 m equipment rack (metal).
                   LiDAR from (0, 0, 1.3), (0.5, +/-1.2, 1.7).
classroom          7 m wide, 3 m high, front wall at 10 m.  floor: floorboard; ceiling:
                   ceiling_board; side walls: plasterboard; front wall: concrete with a
                   3.6 x 1.2 m whiteboard (chipboard); three 1.3 x 1.5 m windows recessed
                   20 cm in the left wall (glass); a door in the right wall (wood);
                   3 x 3 desks, 1.2 x 0.6 m tops at 0.75 m (desk_tops: chipboard) on
                   4 cm legs (desk_legs: metal); teacher's desk and cabinet (wood);
                   locker (metal).  LiDAR from (0, 0, 1.3), (0.5, +/-1.5, 1.8).
street             road 7 m wide (concrete), 0.15 m kerbs (concrete), 1.85 m sidewalks
                   at 0.15 m (concrete), 4 m concrete facades at ``|y| = 5.5`` m from
                   x = 3.4 m to 10.1 m with recessed windows (glass) and a 0.35 m door
                   recess (door: wood); two cars along the right kerb, one on the left:
                   body 0.25-1.0 m high (carN_body: metal), cabin to 1.45 m
                   (carN_cabin: glass), four tyres (carN_tyres: chipboard, standing in
                   for rubber); a 3.5 m sign pole with a plate (pole: metal).
                   LiDAR from (0, 0, 1.5), (0, +/-1.5, 1.8).
parking_lot        ground (concrete) clipped to the radar footprint; three 2.5 m stalls
                   at x = 5.7-10.5 m (one empty, chosen by the seed) with wheel stops
                   (concrete); two cars parked nose-in and one driving along the aisle
                   (car bodies metal, cabins glass, tyres chipboard); 5 m lamp pole with
                   arm and head (lamp_pole: metal) on a 0.6 m base (lamp_base: concrete).
                   LiDAR from (0, 0, 1.5), (0, +/-2, 1.8).
building_corner    exterior building corner on boresight at x = 6 m: two 4 m-high
                   concrete facades at +/-45 deg (facade_a, facade_b), as long as the
                   12 m range allows (about 6.5 m); facade A: a 1.2 x 2.3 m door recess 0.5 m
                   deep (door: wood) and a recessed window, facade B: a window and a
                   2.0 x 2.6 m roller shutter recessed 0.25 m (shutter: metal); windows:
                   glass; a downpipe and two bollards (metal); ground (concrete) around
                   the building.  LiDAR from (0, 0, 1.5), (0.5, +/-2.5, 1.8).
=================  ======================================================================

Typical use::

    from sionna_mmir.benchmark_scenes import build_scene, lidarize_scene, true_materials
    spec = build_scene("hallway", seed=0)
    render_meshes = spec.refined(max_edge=0.25)          # ground truth geometry
    truth = true_materials(spec, seed=0, objects=render_meshes)  # name -> (Nv, 6)
    lidar = lidarize_scene(spec, seed=0)                  # what the fitter gets
    # fitter: load_scene(lidar, materials=spec.materials, ...)
"""
from .catalog import (
    MAX_AZIMUTH_DEG,
    MAX_RANGE_M,
    MIN_FORWARD_M,
    SCENES,
    SceneSpec,
    build_scene,
    rotation_matrix,
)
from .lidar import WAVELENGTH_77GHZ, lidarize, lidarize_scene, mesh_statistics
from .materials import (
    PATCH_MATERIALS,
    MaterialPatch,
    area_weighted_mean,
    describe_true_materials,
    material_patches,
    region_names,
    true_materials,
    true_object_materials,
    true_region_materials,
    true_vertex_materials,
)

__all__ = [
    "MAX_AZIMUTH_DEG",
    "MAX_RANGE_M",
    "MIN_FORWARD_M",
    "PATCH_MATERIALS",
    "SCENES",
    "WAVELENGTH_77GHZ",
    "MaterialPatch",
    "SceneSpec",
    "area_weighted_mean",
    "build_scene",
    "describe_true_materials",
    "lidarize",
    "lidarize_scene",
    "material_patches",
    "mesh_statistics",
    "region_names",
    "rotation_matrix",
    "true_materials",
    "true_object_materials",
    "true_region_materials",
    "true_vertex_materials",
]
