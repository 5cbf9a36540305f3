"""``SceneBasis``: a rendered scene split per object, the base of the effects model.

The residual loop compares a capture with a rendered scene.  Real meshes
never match the radar's scene exactly -- an object's reflectivity, its
phase centre, the radar pose against the LiDAR frame are off -- and such a
*scene mismatch* is organised per object: it changes one object's return on
every channel, while a sensor effect changes every object's return alike.
To let scene-side explanations compete with sensor effects, the base model
is kept as one ADC per object (the strongest objects of the render; the rest
summed into one more component)::

    b[f, t, r, c, k] = sum_o B_o[t, r, c, k]

with, for each component, the energy-weighted mean direction ``u_o`` from
the array's phase centre to its paths and its mean range, so a scene-side
effect can move it: a pose offset ``(d, w)`` (translation [m], small
rotation [rad], scene frame) lengthens path ``o`` between Tx ``t`` and Rx
``r`` by ``-u_o . (2 d + w x (e_t + e_r))`` (``e`` the elements' offsets
from the phase centre), exactly for a compact object and to first order in
the spread of its directions otherwise.

Built by :meth:`SceneBasis.from_paths` from the solver's
:class:`~sionna_mmir.paths.RadarPaths` (with their
:class:`~sionna_mmir.paths.radar_paths.PathGeometry`).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InputValueError
from ..fmcw.synthesize import synthesize_adc
from ..radar.config import SPEED_OF_LIGHT

#: name of the component that sums the objects not kept on their own
REST = "rest"


#: objects under this share of the render's energy join the rest
#: (:meth:`SceneBasis.from_paths`).  The render's shares are the mesh's
#: materials, not the capture's: in the suite's 25 m hall
#: (``make_case(room_scale=2.5)``) the floor beside the radar renders at
#: -2.4 dB of the energy, the far wall and two corner reflectors at 11-14 m
#: at -29 to -37 dB.  Under a -30 dB bar they shared the rest's one gain,
#: and the loop took a per-channel gain on the clean capture and movers
#: for ego motion.  -50 dB keeps them: a capture's dynamic range after
#: range and channel integration (the suite's 35 dB per sample, plus ~30)
#: reaches that far.
MIN_SHARE = 1e-5


@dataclasses.dataclass
class SceneBasis:
    """Per-object ADC of a rendered scene.

    Parameters
    ----------
    names : list of str
        Component names (objects, and :data:`REST` for the others).
    adc : numpy.ndarray
        ``[K, T, R, C, N]`` complex128 ADC of each component (one frame).
    directions : numpy.ndarray
        ``[K, 3]`` unit mean direction from the array centre (scene frame).
    ranges : numpy.ndarray
        ``[K]`` energy-weighted mean range [m].
    offsets_tx, offsets_rx : numpy.ndarray
        ``[T, 3]`` / ``[R, 3]`` element offsets from the array centre (scene frame) [m].
    rotation : numpy.ndarray
        ``[3, 3]`` radar -> scene rotation (for reports in the radar frame).
    shares : numpy.ndarray
        ``[K]`` fraction of the render's energy in each component.
    """

    names: list
    adc: np.ndarray
    directions: np.ndarray
    ranges: np.ndarray
    offsets_tx: np.ndarray
    offsets_rx: np.ndarray
    rotation: np.ndarray
    shares: np.ndarray
    #: large flat objects of the scene as ``[(name, point [3], unit normal [3])]``
    #: in the radar frame (:func:`mesh_planes`), e.g. for multipath ghosts
    planes: list = dataclasses.field(default_factory=list)
    #: the scene's ground: flat objects below the radar that face up, as
    #: triangles in the radar frame (:func:`mesh_grounds`); nothing is seen
    #: through them
    grounds: list = dataclasses.field(default_factory=list)

    @property
    def num_components(self) -> int:
        """``K``."""
        return len(self.names)

    def total(self) -> np.ndarray:
        """``sum_o B_o``, ``[T, R, C, N]``."""
        return self.adc.sum(axis=0)

    @classmethod
    def from_paths(cls, paths, radar, max_objects: int = 8, min_share: float = MIN_SHARE,
                   rotation=None) -> "SceneBasis":
        """Split rendered paths by the object of their first interaction.

        Parameters
        ----------
        paths : RadarPaths
            Solver output with its :attr:`~RadarPaths.geometry`.
        radar : RadarConfig
            The radar the paths were rendered for.
        max_objects : int
            Most objects kept as components of their own (strongest first).
        min_share : float
            Objects under this fraction of the render's energy join :data:`REST`
            (:data:`MIN_SHARE`); under 1 / 100 of it they are left out.
        rotation : array_like, optional
            ``[3, 3]`` radar -> scene rotation (default from ``radar.orientation``).

        Returns
        -------
        SceneBasis
        """
        if paths.geometry is None or paths.num_paths == 0:
            raise InputValueError("SceneBasis: the render has no paths (no ray hits the scene)")
        a, tau, rate = paths.numpy()
        geo = paths.geometry.numpy()
        parts = _object_adc(radar, a, tau, rate, geo["objects"], paths.geometry.object_names,
                            min_share)
        keep, rest = _choose(parts, max_objects, min_share)
        centre = np.concatenate([geo["tx"], geo["rx"]]).mean(axis=0)
        power = np.sum(np.abs(a) ** 2, axis=(0, 1))
        total = sum(float(np.sum(np.abs(x) ** 2)) for _, _, x in parts)
        adc, dirs, rngs, shares, names = [], [], [], [], []
        groups = [(name, sel, x) for name, sel, x in keep]
        if rest:
            groups.append((REST, np.any([sel for _, sel, _ in rest], axis=0),
                           sum(x for _, _, x in rest)))
        for name, sel, x in groups:
            d = geo["x_rx"][sel] - centre
            dist = np.linalg.norm(d, axis=1)
            w = power[sel] / max(power[sel].sum(), 1e-300)
            u = (w[:, None] * d / np.maximum(dist, 1e-9)[:, None]).sum(axis=0)
            names.append(name)
            adc.append(x)
            dirs.append(u / max(np.linalg.norm(u), 1e-12))
            rngs.append(float(np.sum(w * dist)))
            shares.append(float(np.sum(np.abs(x) ** 2)) / max(total, 1e-300))
        if rotation is None:
            from ..radar.config import rotation_matrix

            rotation = rotation_matrix(radar.orientation)
        return cls(names=names, adc=np.stack(adc).astype(np.complex128), directions=np.array(dirs),
                   ranges=np.array(rngs), offsets_tx=geo["tx"] - centre,
                   offsets_rx=geo["rx"] - centre, rotation=np.asarray(rotation, float),
                   shares=np.array(shares))

    # ----------------------------------------------------------- delay maps
    def pose_delay_matrix(self) -> np.ndarray:
        """``[K, T, R, 6]`` d(delay)/d(pose) [s per m | s per rad] of each component
        and pair, for a pose offset ``(d_x, d_y, d_z, w_x, w_y, w_z)`` (scene frame).

        Each element sees the component's point (``ranges`` along
        ``directions`` from the array centre) along its own direction, so the
        map stays right in the near field of wide arrays (a cascade's 8 cm
        aperture at 3 m turns a centre-direction approximation into a
        0.3 rad phase error for a 6 mm shift).  Rotations are about the array
        centre: element ``e`` moves by ``w x e``.
        """
        points = self.directions * self.ranges[:, None]            # [K, 3]

        def towards(offsets):
            d = points[:, None, :] - offsets[None]                 # [K, E, 3]
            return d / np.linalg.norm(d, axis=-1, keepdims=True)

        u_t, u_r = towards(self.offsets_tx), towards(self.offsets_rx)
        d_trans = -(u_t[:, :, None, :] + u_r[:, None, :, :])
        # -u . (w x e) = -w . (e x u)
        rot_t = -np.cross(self.offsets_tx[None], u_t)               # [K, T, 3]
        rot_r = -np.cross(self.offsets_rx[None], u_r)               # [K, R, 3]
        d_rot = rot_t[:, :, None, :] + rot_r[:, None, :, :]
        return np.concatenate([d_trans, d_rot], axis=-1) / SPEED_OF_LIGHT


def _object_adc(radar, a, tau, rate, objects, object_names, min_share):
    """``[(name, path mask, ADC)]`` of every object with at least ``min_share``
    of the render's path power / 100 (the others cannot matter coherently)."""
    power = np.sum(np.abs(a) ** 2, axis=(0, 1))
    total = float(power.sum())
    if not total > 0:
        raise InputValueError("SceneBasis: the render carries no power")
    per = np.bincount(objects, weights=power, minlength=len(object_names))
    out = []
    for o in np.flatnonzero(per >= 1e-2 * min_share * total):
        sel = objects == o
        out.append((object_names[int(o)], sel,
                    synthesize_adc(radar, a[..., sel], tau[..., sel],
                                   None if rate is None else rate[..., sel])))
    return out


def _choose(parts, max_objects, min_share):
    """Split ``parts`` into the components kept on their own (strongest by their
    coherent ADC energy, at least ``min_share`` of the total) and the rest."""
    energy = np.array([float(np.sum(np.abs(x) ** 2)) for _, _, x in parts])
    order = np.argsort(energy)[::-1]
    total = max(float(energy.sum()), 1e-300)
    keep = [int(i) for i in order if energy[i] >= min_share * total][:max(int(max_objects), 1)]
    return [parts[i] for i in keep], [parts[i] for i in range(len(parts)) if i not in keep]


def _in_radar_frame(obj, radar):
    """``(vertices [V, 3], faces [M, 3])`` of a mesh object, the vertices in
    ``radar``'s frame (its ``position`` and ``orientation``) [m]."""
    from ..radar.config import rotation_matrix

    v = np.asarray(obj.vertex_positions, float).reshape(-1, 3)
    f = np.asarray(obj.faces, int).reshape(-1, 3)
    return (v - np.asarray(radar.position, float)) @ rotation_matrix(radar.orientation), f


def mesh_planes(objects, radar, min_area: float = 1.0, tol: float = 0.02) -> list:
    """Large flat objects of a scene as planes in the radar frame.

    An object is a plane when every vertex lies within ``tol`` [m] of the
    least-squares plane through its vertices (smallest singular vector) and
    its triangles cover at least ``min_area`` [m^2] (floors, walls, ceilings;
    not a corner reflector or a cabinet).

    Parameters
    ----------
    objects : dict
        Name -> object with ``vertex_positions [V, 3]`` and ``faces [M, 3]``
        (scene frame), e.g. :attr:`RadarScene.objects`.
    radar : RadarConfig
        Its ``position`` and ``orientation`` place the radar frame.

    Returns
    -------
    list of (str, numpy.ndarray, numpy.ndarray)
        ``(name, point [3], unit normal [3])``, radar frame, the normal
        pointing to the radar's side.
    """
    out = []
    for name, obj in objects.items():
        v, f = _in_radar_frame(obj, radar)
        if len(v) < 3 or not len(f):
            continue
        c = v.mean(axis=0)
        n = np.linalg.svd(v - c, full_matrices=False)[2][-1]
        area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
                                    axis=1).sum()
        if np.abs((v - c) @ n).max() > tol or area < min_area:
            continue
        n = -n if np.dot(c, n) > 0 else n                              # towards the radar
        out.append((str(name), c, n))
    return out


#: a flat object is ground when its upward normal is within this angle of
#: the radar frame's +z [deg] (:func:`mesh_grounds`)
GROUND_TILT_DEG = 30.0


def mesh_grounds(objects, radar, planes=None) -> list:
    """The flat objects of a scene that are ground: below the radar, facing
    up, as triangles in the radar frame.

    A floor or the ground is opaque at millimetre waves (concrete, soil,
    asphalt), so nothing the radar sees lies behind it; what appears there
    is a multipath image via the ground or a sensor artefact (a point fitted
    there is refused: :meth:`~sionna_mmir.effects.library.scatterer.MissingScatterer.fitted_gain_floor`).
    Walls are not included: plasterboard and glass pass 77 GHz.

    Parameters
    ----------
    objects, radar :
        As :func:`mesh_planes` (the radar frame's +z is up).
    planes : list, optional
        ``mesh_planes(objects, radar)`` when already at hand.

    Returns
    -------
    list of (str, numpy.ndarray, numpy.ndarray, numpy.ndarray, numpy.ndarray)
        ``(name, centre [3], unit normal [3] (up), in-plane axes [2, 3],
        triangles [M, 3, 2])`` [m], radar frame: the object's triangles in
        its plane, relative to the centre.
    """
    cos_tilt = np.cos(np.radians(GROUND_TILT_DEG))
    out = []
    for name, c, n in mesh_planes(objects, radar) if planes is None else planes:
        if n[2] < cos_tilt:                           # not facing up: a wall or a ceiling
            continue
        v, f = _in_radar_frame(objects[name], radar)
        axes = np.linalg.svd(np.vstack([n, np.zeros(3)]))[2][1:]   # two axes normal to n
        out.append((str(name), c, n, axes, ((v - c) @ axes.T)[f]))
    return out


#: how far below the ground a fitted point must lie to count as seen
#: through it [m] (:func:`behind_ground`): the suite's floor clutter is fitted
#: within 0.1 m of the floor, a target's image via the floor lies as far
#: below it as the target stands above (0.5-1.6 m in the suite's rooms and
#: halls)
GROUND_MARGIN_M = 0.3


def behind_ground(point, grounds, margin: float = GROUND_MARGIN_M) -> bool:
    """Whether the line of sight from the radar (the origin of the radar
    frame) to ``point`` [3] crosses one of ``grounds`` (:func:`mesh_grounds`)
    inside one of its triangles, the point more than ``margin`` [m] below it."""
    p = np.asarray(point, float)
    for _, c, n, axes, tris in grounds:
        if np.dot(c - p, n) <= margin:           # not below the plane
            continue
        t = np.dot(c, n) / np.dot(p, n)          # the crossing, as a share of the way
        if 0.0 < t < 1.0 and _in_triangles(axes @ (t * p - c), tris):
            return True
    return False


def _in_triangles(q, tris, eps: float = 1e-9) -> bool:
    """Whether the 2-D point ``q`` lies in one of ``tris [M, 3, 2]``."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]

    def side(u, v):
        return (v[:, 0] - u[:, 0]) * (q[1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (q[0] - u[:, 0])

    s1, s2, s3 = side(a, b), side(b, c), side(c, a)
    inside = ((s1 >= -eps) & (s2 >= -eps) & (s3 >= -eps)) | \
             ((s1 <= eps) & (s2 <= eps) & (s3 <= eps))
    return bool(np.any(inside))
