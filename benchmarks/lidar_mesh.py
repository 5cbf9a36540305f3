"""A deterministic LiDAR-reconstruction-like room mesh for benchmarks.

``lidar_room_mesh(n_triangles, seed)`` builds a room seen by a radar at the
origin looking along ``+x``: a floor, four walls (no ceiling, so the radar is
not enclosed) and a few boxes standing on the floor.  Every planar face is
tessellated into a regular grid of quads (two triangles each), with the
triangle budget shared in proportion to area, so the total is close to
``n_triangles``.  Like a surface reconstructed from LiDAR points:

* every grid vertex is displaced along its face normal by a Gaussian of a few
  millimetres (``jitter_m``, default 3 mm), so the per-vertex normals that
  trimesh computes are misaligned with the true planes;
* faces are separate sheets (no shared vertices across a room corner or a
  box edge), leaving the small cracks reconstructions have;
* a few small holes (discs of 5-20 cm radius) are cut out of the walls and
  the floor.

Room (metres, scene frame): ``x`` in ``[-1, 7]``, ``y`` in ``[-3, 3]``,
``z`` in ``[-1, 2]`` (floor at ``z = -1``, the radar 1 m above it).
The same ``(n_triangles, seed)`` always gives the same mesh, bit for bit.
"""
from __future__ import annotations

import math

import numpy as np

#: room extent [m]
ROOM_X = (-1.0, 7.0)
ROOM_Y = (-3.0, 3.0)
ROOM_Z = (-1.0, 2.0)

#: boxes: (centre x, centre y, size x, size y, height) [m], standing on the floor
BOXES = (
    (3.0, 1.2, 0.8, 0.6, 0.9),
    (4.5, -1.5, 1.2, 0.8, 0.5),
    (5.5, 0.5, 0.5, 0.5, 1.6),
    (2.2, -0.8, 0.4, 0.6, 0.4),
)


def _rectangles():
    """Planar rectangles ``(origin, edge_u, edge_v)``; normal = u x v points into the room."""
    x0, x1 = ROOM_X
    y0, y1 = ROOM_Y
    z0, z1 = ROOM_Z
    o = np.array
    rects = [
        (o([x0, y0, z0]), o([x1 - x0, 0, 0]), o([0, y1 - y0, 0])),        # floor, +z
        (o([x1, y0, z0]), o([0, y1 - y0, 0]), o([0, 0, z1 - z0])),        # front wall, -x
        (o([x0, y1, z0]), o([0, y0 - y1, 0]), o([0, 0, z1 - z0])),        # back wall, +x
        (o([x0, y0, z0]), o([x1 - x0, 0, 0]), o([0, 0, z1 - z0])),        # right wall, +y
        (o([x1, y1, z0]), o([x0 - x1, 0, 0]), o([0, 0, z1 - z0])),        # left wall, -y
    ]
    for cx, cy, sx, sy, h in BOXES:
        bx0, bx1, by0, by1 = cx - sx / 2, cx + sx / 2, cy - sy / 2, cy + sy / 2
        rects += [
            (o([bx0, by0, z0 + h]), o([sx, 0, 0]), o([0, sy, 0])),        # top, +z
            (o([bx0, by1, z0]), o([0, -sy, 0]), o([0, 0, h])),            # -x face
            (o([bx1, by0, z0]), o([0, sy, 0]), o([0, 0, h])),             # +x face
            (o([bx0, by0, z0]), o([0, 0, h]), o([sx, 0, 0])),             # -y face
            (o([bx1, by1, z0]), o([0, 0, h]), o([-sx, 0, 0])),            # +y face
        ]
    return [(a.astype(np.float64), b.astype(np.float64), c.astype(np.float64)) for a, b, c in rects]


def _grid(origin, eu, ev, nu, nv):
    """Vertices ``[(nu+1)(nv+1), 3]`` and faces ``[2 nu nv, 3]`` of a rectangle grid."""
    s = np.linspace(0.0, 1.0, nu + 1)
    t = np.linspace(0.0, 1.0, nv + 1)
    ss, tt = np.meshgrid(s, t, indexing="ij")
    verts = origin + ss.reshape(-1, 1) * eu + tt.reshape(-1, 1) * ev
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = (i * (nv + 1) + j).ravel()
    b = a + (nv + 1)
    faces = np.concatenate([np.stack([a, b, b + 1], 1), np.stack([a, b + 1, a + 1], 1)])
    return verts, faces


def lidar_room_mesh(n_triangles: int = 100_000, seed: int = 0, jitter_m: float = 3e-3,
                    num_holes: int = 6):
    """A room-like ``trimesh.Trimesh`` of about ``n_triangles`` triangles (see module doc).

    ==============  =========================================================
    n_triangles     target triangle count (the result is within a few % of it,
                    minus the holes); at least ~200
    seed            seed of the vertex jitter and the hole positions
    jitter_m        standard deviation of the along-normal jitter [m]
    num_holes       number of small disc-shaped holes (walls and floor)
    ==============  =========================================================
    """
    import trimesh

    n_triangles = int(n_triangles)
    if n_triangles < 200:
        raise ValueError(f"n_triangles must be >= 200, got {n_triangles}")
    rng = np.random.default_rng(seed)
    rects = _rectangles()
    areas = np.array([np.linalg.norm(np.cross(u, v)) for _, u, v in rects])
    quads = n_triangles / 2.0 * areas / areas.sum()
    verts_all, faces_all, offset = [], [], 0
    hole_faces = []
    # holes only in the room shell (floor + 4 walls), a few per run
    hole_rect = rng.integers(0, 5, size=num_holes)
    hole_st = rng.uniform(0.1, 0.9, size=(num_holes, 2))
    hole_r = rng.uniform(0.05, 0.20, size=num_holes)
    for k, (o, eu, ev) in enumerate(rects):
        lu, lv = np.linalg.norm(eu), np.linalg.norm(ev)
        nu = max(1, int(round(math.sqrt(quads[k] * lu / lv))))
        nv = max(1, int(round(quads[k] / nu)))
        v, f = _grid(o, eu, ev, nu, nv)
        n = np.cross(eu, ev)
        n /= np.linalg.norm(n)
        v = v + rng.normal(0.0, jitter_m, size=(len(v), 1)) * n
        # faces whose centroid lies in one of this rectangle's holes
        cen = v[f].mean(axis=1)
        drop = np.zeros(len(f), dtype=bool)
        for h in np.nonzero(hole_rect == k)[0]:
            c = o + hole_st[h, 0] * eu + hole_st[h, 1] * ev
            d = cen - c
            d -= np.outer(d @ n, n)
            drop |= np.linalg.norm(d, axis=1) < hole_r[h]
        hole_faces.append(int(drop.sum()))
        verts_all.append(v)
        faces_all.append(f[~drop] + offset)
        offset += len(v)
    vertices = np.concatenate(verts_all)
    faces = np.concatenate(faces_all)
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    # drop the vertices only the holes used (keeps the mesh tidy; order is stable)
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    if not used.all():
        remap = np.cumsum(used) - 1
        mesh = trimesh.Trimesh(vertices=vertices[used], faces=remap[faces], process=False)
    mesh.metadata["holes_triangles"] = sum(hole_faces)
    return mesh


if __name__ == "__main__":
    import sys

    n = int(float(sys.argv[1])) if len(sys.argv) > 1 else 100_000
    m = lidar_room_mesh(n)
    print(f"{len(m.faces)} triangles, {len(m.vertices)} vertices, "
          f"{m.metadata['holes_triangles']} removed for holes, area {m.area:.1f} m^2")
