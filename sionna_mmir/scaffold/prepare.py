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
correlation against the ground truth): ``docs/results.md``, scaffold ceiling.

:class:`ScaffoldOptions` holds the chain's settings with two named presets:
``ScaffoldOptions.none()`` (the meshes as given: a clean CAD or
photogrammetry mesh) and ``ScaffoldOptions.lidar()`` (the whole chain: a
LiDAR scan, as the benchmark scaffolds).
"""
from __future__ import annotations

import dataclasses

from ..errors import InputValueError
from .denoise import denoise_meshes
from .planes import snap_planes
from .shading import MIN_CURVED, auto_shaded, curved_fraction, flat_shaded

#: shading choices: ``auto`` (per object, :func:`.shading.auto_shaded`),
#: ``flat``, ``shared`` (the scan's shared vertices and averaged normals)
SHADINGS = ("auto", "flat", "shared")


@dataclasses.dataclass(frozen=True)
class ScaffoldOptions:
    """Settings of :func:`prepare_scaffold`.

    Parameters
    ----------
    denoise : bool
        MLS-denoise first (:func:`.denoise.denoise_meshes`).
    planes : bool
        Snap planar regions of the objects that are not curved
        (:func:`.planes.snap_planes`).
    shading : {"auto", "flat", "shared"}
        Shading normals: per object (curved objects crease-split, the others
        flat), flat, or the meshes' shared vertex normals.
    """

    denoise: bool = True
    planes: bool = True
    shading: str = "auto"

    def __post_init__(self):
        if self.shading not in SHADINGS:
            raise InputValueError(f"scaffold shading must be one of {SHADINGS}, "
                                  f"got {self.shading!r}")

    @classmethod
    def none(cls) -> "ScaffoldOptions":
        """The meshes as given (no denoising, no snapping, their own normals)."""
        return cls(denoise=False, planes=False, shading="shared")

    @classmethod
    def lidar(cls) -> "ScaffoldOptions":
        """The whole chain, for LiDAR scans (the benchmark scaffolds)."""
        return cls()

    @property
    def active(self) -> bool:
        """Whether the chain changes the meshes at all."""
        return self.denoise or self.planes or self.shading != "shared"


def prepare_scaffold(meshes: dict, options: ScaffoldOptions | None = None, *,
                     denoise: bool | None = None, planes: bool | None = None,
                     shading: str | None = None) -> dict:
    """The scaffold the fitters get from a scan.

    Parameters
    ----------
    meshes : dict
        Name -> ``trimesh.Trimesh`` [m].
    options : ScaffoldOptions, optional
        The chain's settings (default :meth:`ScaffoldOptions.lidar`);
        ``denoise``, ``planes`` and ``shading`` override its fields.

    Returns
    -------
    dict
        Name -> ``trimesh.Trimesh``, same keys and order.
    """
    options = options or ScaffoldOptions()
    changes = {k: v for k, v in (("denoise", denoise), ("planes", planes),
                                 ("shading", shading)) if v is not None}
    options = dataclasses.replace(options, **changes)
    denoise, planes, shading = options.denoise, options.planes, options.shading
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
