"""``RadarPathSolver``: Rx-centric, MIMO-coherent, differentiable radar paths.

A subclass of Sionna RT's ``PathSolver`` that returns
:class:`~sionna_mmir.paths.radar_paths.RadarPaths` (per Tx-Rx pair amplitudes
and delays, ready for :func:`~sionna_mmir.fmcw.synthesize_adc`) with every
quantity inside the Dr.Jit AD graph.

Estimator (paper eq. 3, Sec. 3.1).  Candidate rays leave the array's phase
centre (:mod:`.sampling`: Monte Carlo rays in a cone, or a facet
quadrature); rays that hit the scene are followed for up to ``max_depth``
interactions, and at every interaction ``x_l`` the path is connected
deterministically to the transmitter.  Interaction points are traced by
Mitsuba outside AD and rebuilt inside AD from (triangle, barycentrics) and
the differentiable vertex tensors (:mod:`.geometry`).  At each depth the
call runs the transport stages of :mod:`.transport` in order:

1. surface -- local geometry, deferred BSDF weight, materials;
2. connection -- the shadow ray to the Tx;
3. coherent -- the physical-optics field of specular chains (the exit
   aperture on the last surface; under the facet quadrature clipped to
   each node's lit footprint, :mod:`.transport.aperture`);
4. scattered -- the BSDF speckle field and its reciprocal twin;
5. continuation -- mirror or BSDF sample (or FSD diffraction), roulette,
   the next segment;

and :mod:`.assemble` forms the per-element legs (MIMO ray reuse: every
Tx-Rx pair gets its own exact delay).  The Rayleigh factor ``eta`` splits
the reflected energy between the coherent and the scattered part (our
modelling choice; the paper sums square roots of power throughputs, which
does not converge for coherent surfaces).

Motion: objects with a velocity and a moving radar give each path a delay
rate ``d tau / dt`` for Doppler across chirps and TDM slots (not in the
paper; :mod:`.transport.motion`).
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radio_materials.fresnel import SPEED_OF_LIGHT
from ..utils.backend import init_backend
from .assemble import assemble, empty_paths
from .geometry import SceneGeometry, Tape
from .options import SolverOptions
from .polarization import Field, transverse
from .pose import Pose
from .radar_paths import RadarPaths
from .sampling import make_sampler
from .transport import aperture, coherent, continuation, motion, scattered
from .transport.connection import connect
from .transport.diffraction import fsd_setup
from .transport.state import Emission, PathState, SolverContext, zeros
from .transport.surface import at_surface

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
from sionna.rt import PathSolver  # noqa: E402


def radar_of(scene, radar):
    """``radar``, or the scene's radar; raises ``ConfigError`` if neither."""
    radar = radar if radar is not None else getattr(scene, "radar", None)
    if radar is None:
        raise ConfigError("RadarPathSolver: no radar given and the scene has none "
                          "(load_scene(..., radar=RadarConfig...) or pass radar=)")
    return radar


class RadarPathSolver(PathSolver):
    """Differentiable radar path solver (see the module docstring).

    Parameters
    ----------
    deterministic : bool
        Passed to Sionna's ``PathSolver``.

    Notes
    -----
    Call as ``solver(scene, radar=None, options=None, *, samples=None,
    **overrides)``: ``scene`` a :class:`~sionna_mmir.scene.RadarScene`,
    ``radar`` a :class:`~sionna_mmir.radar.RadarConfig` (default
    ``scene.radar``; the pose is the scene's differentiable ``position`` /
    ``orientation``), ``options`` a :class:`SolverOptions` (or a dict; the
    defaults when ``None``) with keyword ``overrides`` of its fields, and
    ``samples`` the ``paths.samples`` of an earlier call to replay its
    discrete decisions (frozen samples, e.g. for finite-difference checks).
    Returns :class:`~sionna_mmir.paths.RadarPaths`.
    """

    def __init__(self, deterministic: bool = True):
        super().__init__(deterministic=deterministic)

    def __call__(self, scene, radar=None, options: SolverOptions | dict | None = None, *,
                 samples=None, **overrides) -> RadarPaths:
        opts = SolverOptions.resolve(options, **overrides)
        ctx = self._context(scene, radar_of(scene, radar), opts, samples)
        cands = ctx.sampler.candidates(ctx.geo, ctx.pose, ctx.c_w, ctx.wavelength)
        N = cands.count
        if N == 0:
            return empty_paths(ctx.num_tx, ctx.num_rx, 0)
        st = self._first_hits(ctx, cands)
        if st is None:
            return empty_paths(ctx.num_tx, ctx.num_rx, N)
        K = st.width
        emissions = []
        for depth in range(1, opts.max_depth + 1):
            surf = at_surface(ctx, st, depth)
            conn = connect(ctx, st, surf)
            coherent.unfold(st, surf, depth)
            aperture.clip(ctx, st, depth)
            emissions += self._emit(ctx, st, surf, conn, depth)
            if depth == opts.max_depth:
                break
            continuation.continue_paths(ctx, st, surf, depth)
        moving = opts.velocities is not None or opts.radar_velocity is not None
        paths = assemble(ctx, emissions, N, K, moving, object_names=ctx.geo.names)
        paths.samples = samples if samples is not None else (ctx.geo.record, ctx.tape.values)
        return paths

    # ------------------------------------------------------------------ stages
    def _context(self, scene, radar, opts, samples) -> SolverContext:
        """Validate the scene and build the call's constants."""
        _check_scene(scene, radar, opts)
        geo = SceneGeometry(scene)
        geo.validate()
        if samples is not None:
            geo.replay = list(samples[0])
            tape = Tape(samples[1])
        else:
            geo.record = []
            tape = Tape()
        pose = Pose.from_tensors(scene.position, scene.orientation)
        wavelength = SPEED_OF_LIGHT / float(dr.detach(scene.frequency)[0]) \
            if dr.width(scene.frequency) else radar.wavelength
        centre = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
        ctx = SolverContext(
            options=opts, geo=geo, tape=tape, pose=pose, ptx=_pattern(opts.tx_pattern),
            prx=_pattern(opts.rx_pattern), wavelength=wavelength,
            frequency=SPEED_OF_LIGHT / wavelength, c_w=pose.point(centre),
            tx_w=pose.point(radar.tx_positions), rx_w=pose.point(radar.rx_positions),
            num_tx=radar.num_tx, num_rx=radar.num_rx, sampler=make_sampler(opts),
            velocities=motion.velocity_table(geo.names, opts.velocities),
            v_radar=motion.radar_velocity(opts.radar_velocity))
        if opts.check_inside and samples is None:
            _check_inside(geo, dr.detach(ctx.c_w))
        return ctx

    def _first_hits(self, ctx, cands) -> PathState | None:
        """Trace the candidates, keep the hits and start the path state."""
        geo, tape = ctx.geo, ctx.tape
        valid, obj, face, u, v = geo.trace(cands.origin, cands.direction)
        valid = ctx.sampler.keep_hits(valid, face, cands, tape)
        keep = dr.compress(valid)
        K = dr.width(keep)
        if K == 0:
            return None
        pdf = tape.freeze(dr.gather(mi.Float, cands.pdf, keep))
        obj, face = dr.gather(mi.UInt32, obj, keep), dr.gather(mi.UInt32, face, keep)
        u, v = dr.gather(mi.Float, u, keep), dr.gather(mi.Float, v, keep)
        ctx.n_est = ctx.sampler.estimator_count(cands.count)
        ctx.rng = mi.PCG32(size=K, initstate=dr.opaque(mi.UInt64,
                                                       int(ctx.options.seed) + 0x9E3779B9))
        if ctx.options.diffraction:
            ctx.fsd = fsd_setup(geo, ctx.wavelength, ctx.options.fsd_width)
        it = geo.interaction(dr.full(mi.Bool, True, K), obj, face, u, v, tape)
        sub = ctx.sampler.first_triangle(it, cands, keep)
        st = _start_state(ctx, it, pdf, sub)
        st.aperture = ctx.sampler.aperture(ctx.options, keep, face, it.tri, sub)
        return st

    def _emit(self, ctx, st, surf, conn, depth) -> list:
        """Paths ending at this depth: the coherent chain, the scattered
        speckle (with the depth-1 coherent term) and the reciprocal twin."""
        opts, K = ctx.options, st.width
        out = []
        C_re, C_im = zeros(K), zeros(K)
        if opts.coherent:
            wr, wi, m = coherent.coherent_field(ctx, st, surf, conn, depth)
            if depth == 1:
                C_re += dr.select(m, wr, 0.0)
                C_im += dr.select(m, wi, 0.0)
            else:
                out.append(coherent.coherent_emission(st, surf, wr, wi, m, conn.rate, depth))
        if opts.scattering:
            sc_re, sc_im = scattered.scattered_field(ctx, st, surf, conn)
            C_re += sc_re
            C_im += sc_im
        if depth == 1 or opts.scattering:   # (deeper coherent terms were added above)
            out.append(Emission(C_re, C_im, surf.x, st.x1, zeros(K), st.chain, conn.rate, depth,
                                conn.ok, st.obj1))
        if opts.scattering and opts.reciprocal and depth > 1:
            out.append(scattered.reciprocal_emission(st, surf, conn, sc_re, sc_im, depth))
        return out


def _start_state(ctx, it, pdf, tri1) -> PathState:
    """The path state at the first interaction (width ``K``; ``tri1`` the
    region the first interaction integrates over)."""
    K = dr.width(pdf)
    x1 = it.p
    cw_k = dr.zeros(mi.Point3f, K) + ctx.c_w
    k0 = dr.normalize(x1 - cw_k)
    L0_det = ctx.tape.freeze(dr.norm(x1 - cw_k))
    e_r = ctx.pose.to_scene(ctx.prx.polarization(ctx.pose.to_radar(k0)))
    eye = [mi.Vector3f(1.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0), mi.Vector3f(0.0, 0.0, 1.0)]
    return PathState(it=it, E=Field(transverse(e_r, k0)), inv_p=dr.ones(mi.Float, K),
                     coh=dr.full(mi.Bool, True, K), beta=zeros(K), p_area=zeros(K),
                     chain=zeros(K), prev_p=cw_k, rate_chain=zeros(K), first_pdf=pdf, x1=x1,
                     k0=k0, L0_det=L0_det, cw_k=cw_k, tri1=tri1,
                     U=(eye, mi.Vector3f(0.0, 0.0, 0.0)), x_star=x1, obj1=it.obj)


def _pattern(spec):
    from ..radio_devices import make_pattern

    return make_pattern(spec)


def _check_scene(scene, radar, opts) -> None:
    if not hasattr(scene, "mesh_objects"):
        raise ConfigError("RadarPathSolver needs a sionna_mmir RadarScene (sionna_mmir.load_scene)")
    scene.check_radar(radar)
    for name in (opts.velocities or {}):
        if name not in scene.mesh_objects:
            raise ConfigError(f"velocities: unknown object {name!r}")


def _check_inside(geo, c) -> None:
    """Raise if the array centre is enclosed (all probe rays hit back faces)."""
    dirs = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                     [1, 1, 1], [-1, -1, 1], [1, -1, -1], [-1, 1, -1]], dtype=np.float32)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    n = len(dirs)
    d = mi.Vector3f(mi.Float(dirs[:, 0]), mi.Float(dirs[:, 1]), mi.Float(dirs[:, 2]))
    o = dr.zeros(mi.Point3f, n) + c
    with dr.suspend_grad():
        valid, obj, face, u, v = geo._trace(o, d, True)
        it = geo.interaction(valid, obj, face, u, v)
        back = valid & (dr.dot(it.ng, d) > 0)
    if bool(dr.all(back)):
        raise InputValueError("radar is inside closed geometry: every probe ray from the "
                              "array centre hits a back face; move the radar or fix the mesh")
