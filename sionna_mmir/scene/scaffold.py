"""From a LiDAR-like scan to the fitting scaffold: denoise, snap planes, shade.

The one place that chains the scan clean-up steps, so that the fit command,
``bench`` and the benchmark runner give both models the same mesh:

1. :func:`.denoise.denoise_meshes` (MLS, radius 3 median edge lengths,
   20 deg crease angle),
2. :func:`.planes.snap_planes` (planar regions onto fitted planes) of every
   object that :func:`.shading.curved_fraction` does not call curved (a
   pole or a bollard keeps its denoised shape),
3. :func:`.shading.flat_shaded` / :func:`.shading.auto_shaded` (or the
   scan's shared vertex normals).

Effect on the benchmark scenes (true materials, no fit, depth 3, RA
correlation against the ground truth): see NOTES.md, session 9.
"""
from __future__ import annotations

from ..errors import InputValueError
from .denoise import denoise_meshes
from .planes import snap_planes
from .shading import MIN_CURVED, auto_shaded, curved_fraction, flat_shaded

#: shading choices: ``auto`` (per object, :func:`.shading.auto_shaded`),
#: ``flat``, ``shared`` (the scan's shared vertices and averaged normals)
SHADINGS = ("auto", "flat", "shared")


def prepare_scaffold(meshes: dict, *, denoise: bool = True, planes: bool = True,
                     shading: str = "auto") -> dict:
    """The scaffold the fitters get from a scan.

    ===========  ==============================================================
    ``meshes``   ``dict`` name -> ``trimesh.Trimesh`` [m]
    ``denoise``  MLS-denoise first (:func:`.denoise.denoise_meshes`)
    ``planes``   snap planar regions of the objects that are not curved
                 (:func:`.planes.snap_planes`, defaults)
    ``shading``  one of :data:`SHADINGS`
    returns      ``dict`` name -> ``trimesh.Trimesh``, same keys and order
    ===========  ==============================================================
    """
    if shading not in SHADINGS:
        raise InputValueError(f"prepare_scaffold: shading must be one of {SHADINGS}, "
                              f"got {shading!r}")
    if not isinstance(meshes, dict) or not meshes:
        raise InputValueError("prepare_scaffold: expected a non-empty dict name -> mesh")
    if denoise:
        meshes = denoise_meshes(meshes, radius=None, crease_angle_deg=20.0)
    if planes:
        flat = {k: m for k, m in meshes.items() if curved_fraction(m) < MIN_CURVED}
        snapped = snap_planes(flat) if flat else {}
        meshes = {k: snapped.get(k, m) for k, m in meshes.items()}
    if shading == "flat":
        meshes = flat_shaded(meshes)
    elif shading == "auto":
        meshes = auto_shaded(meshes)
    return meshes
