"""``RadarPathSolver``: Rx-centric, MIMO-coherent, differentiable radar paths.

A subclass of Sionna RT's ``PathSolver`` that returns
:class:`~sionna_mmir.paths.radar_paths.RadarPaths` (per Tx-Rx pair amplitudes
and delays, ready for :func:`~sionna_mmir.fmcw.synthesize_adc`) with every
quantity inside the Dr.Jit AD graph.

Estimator (paper eq. 3, Sec. 3.1)
---------------------------------
``N`` candidate rays leave the array's phase centre ``c`` with directions drawn
from a cosine-weighted cone about the boresight (half-angle ``cone_angle``,
``rho(w) = cos(theta) / (pi sin^2(cone_angle))``; the full hemisphere by
default).  Rays that hit the scene are kept (``K <= N``; misses contribute
zero).  Each kept ray is followed for up to ``max_depth`` interactions, and at
every interaction ``x_l`` the path is connected **deterministically to the
transmitter** (a shadow ray from ``x_l`` to the array centre), giving one
path per ray and depth.  Interaction points are traced by Mitsuba outside AD
and rebuilt inside AD from (triangle, barycentrics) and the differentiable
vertex tensors (:mod:`.geometry`).

At each interaction the reflected energy is split by the Rayleigh factor
``eta`` into two parts (our modelling choice, documented in the README):

*coherent* -- the mean-surface reflection, rendered as a **physical-optics
(Kirchhoff) field**: a ray that reached ``x_l`` through specular reflections
only (a geometric-optics chain from the receiver, Jones-transported,
:mod:`.polarization`) radiates towards the transmitter with

    a_po = j / (4 pi) sqrt(G_t G_r) (e_t . E_refl) c_po sqrt(eta_b) / (d_t L)  / (N p_A)

where ``L`` is the unfolded receiver-side length, ``c_po = (cos_in + cos_t)/2``
the Kirchhoff obliquity, ``eta_b = exp(-(k sigma_h (cos_in + cos_t))^2)`` the
bistatic coherent loss, ``E_refl`` the field reflected with the complex
P.2040 slab coefficients of the interpolated vertex materials and ``p_A`` the
area density of ``x_l``.  Summed coherently (the carrier phase comes from the
delays), this is an unbiased Monte Carlo estimate of the physical-optics
integral -- the shooting-and-bouncing-rays method -- and reproduces the plate
``4 pi A^2 / lambda^2`` and trihedral RCS.

*scattered* -- the remaining ``1 - eta`` of the energy, distributed by the
mmIR BSDF ``f`` (paper eqs. 5-7, :mod:`sionna_mmir.bsdf.mmwave`, energy gate
from the P.2040 slab and the path's s/p power fractions), rendered as a
speckle field: power

    P_sc = (lambda / 4 pi)^2 G_t G_r (1 - eta) f c_t |E|^2 c_in / (d_t^2 L^2) / (N p_A)

(the bistatic radar equation with ``sigma^0 = 4 pi f c_t c_in``) and a uniform
random phase per path, so that the expected power of the coherent sum is the
Monte Carlo estimate of the scattered power for any ``N``.

Multi-bounce: at each interaction the ray continues along the mirror direction
of the shading normal with probability ``eta`` (field scaled by
``sqrt(eta) R / eta``: unbiased), otherwise along a direction sampled from the
mmIR BSDF (lobe sampling with the balance-heuristic mixture pdf); a path that
scattered once continues as a power-only (incoherent) path.  Russian roulette
ends paths from ``rr_depth`` on.

Reciprocal twins: a path whose receiver-side events are all specular and
whose last event scatters (mirror first, scatter last) has a physical twin
with the order reversed (scatter first, then the specular chain to the
transmitter) that Rx-side sampling with a straight-line Tx connection cannot
produce (the last event would be a delta).  By reciprocity its transfer is
the same; it is added with the Tx and Rx legs swapped (``reciprocal=True``).

MIMO ray reuse (Schuessler et al. 2021): the bounce topology (triangles,
barycentrics, random choices) is found once from the array centre with a
shared seed; only the first leg ``rx_j -> x_1`` and the last leg
``x_l -> tx_i`` (distances, directions, element gains) are evaluated per Tx
and Rx element, so every pair gets its own exact delay and phase.
Amplitudes factor as ``a[i, j, p] = C[p] g_t[i, p] g_r[j, p]``.
Visibility of the two legs and the Fresnel/polarisation terms are taken from
the array centre (the array is millimetres to centimetres across).

Convention: the field terms above are channel coefficients in the
``exp(+j w t)`` / ``exp(-j k r)`` convention of ITU-R P.2040 and Sionna RT
(``h(f) = sum a_s exp(-j 2 pi f tau)``); the beat signal of the FMCW
receiver is ``sum conj(a_s) exp(+j 2 pi f_k tau)``, so ``RadarPaths`` holds
``a = conj(a_s)`` -- the same convention the Sionna RT baseline uses.

Motion: objects with a velocity (``velocities={name: [vx, vy, vz]}``) and a
moving radar (``radar_velocity``) give each path a delay rate
``d tau / dt = sum_l v_l . dL/dx_l / c`` for Doppler across chirps and TDM
slots (not in the paper).
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radio_materials.fresnel import SPEED_OF_LIGHT, complex_permittivity, slab_coefficients
from ..utils.backend import init_backend
from .geometry import SceneGeometry, Tape
from .polarization import Field, mirror, polarization_fractions, reflect_field, transverse
from .pose import Pose
from .radar_paths import PathFactors, RadarPaths
from .triangle_po import triangle_phase_average

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
from sionna.rt import PathSolver  # noqa: E402

from ..bsdf import mmwave  # noqa: E402

#: offset of secondary ray origins along the geometric normal [m]
RAY_EPSILON = 1e-4


def gate_fsd(E, k_in, n, sc):
    """Edge opacity of the FSD lobe: the Fresnel energy gate of the surface."""
    fs, fp = polarization_fractions(E, k_in, n)
    return fs * dr.squared_norm(sc.r_s) + fp * dr.squared_norm(sc.r_p)


def _gather3(v, idx):
    return mi.Point3f(*(dr.gather(mi.Float, v[c], idx) for c in range(3)))


def _radar_of(scene, radar):
    radar = radar if radar is not None else getattr(scene, "radar", None)
    if radar is None:
        raise ConfigError("RadarPathSolver: no radar given and the scene has none "
                          "(load_scene(..., radar=RadarConfig...) or pass radar=)")
    return radar


def _patterns(tx_pattern, rx_pattern, radar):
    from ..radio_devices import make_pattern

    return make_pattern(tx_pattern), make_pattern(rx_pattern)


def cone_directions(u1, u2, cone_angle):
    """Cosine-weighted directions in a cone about ``+z``; returns ``(local, pdf)``.

    Concentric disk mapping (Shirley & Chiu 1997) scaled by
    ``sin(cone_angle)``; ``pdf = cos(theta) / (pi sin^2(cone_angle))`` [1/sr].
    """
    s = math.sin(min(float(cone_angle), math.pi / 2))
    d = mi.warp.square_to_uniform_disk_concentric(mi.Point2f(u1, u2)) * s
    z = dr.safe_sqrt(1.0 - dr.squared_norm(d))
    return mi.Vector3f(d.x, d.y, z), z / (math.pi * s * s)


class RadarPathSolver(PathSolver):
    """Differentiable radar path solver (see the module docstring).

    Call with ``(scene, radar=None, **options)``:

    ===================  =====================================================
    scene                :class:`~sionna_mmir.scene.RadarScene`
    radar                :class:`~sionna_mmir.radar.RadarConfig` (default
                         ``scene.radar``); the pose is the scene's
                         ``position`` / ``orientation`` tensors
    num_rays             candidate rays ``N`` (default 20000)
    max_depth            interactions per path (default 3)
    seed                 seed of the shared sampler (same seed -> identical
                         paths, bit for bit)
    cone_angle_deg       half-angle of the ray cone about boresight
                         (default 90: the hemisphere)
    coherent             include the physical-optics coherent part
    scattering           include the BSDF-scattered part
    tx_pattern,          element patterns (``"cos"``, ``"iso"``,
    rx_pattern           ``"sionna:tr38901"``, or a
                         :class:`~sionna_mmir.radio_devices.BeamPattern`)
    rr_depth             depth from which Russian roulette is applied
    velocities           ``{object: (vx, vy, vz)}`` [m/s] (scene frame)
    radar_velocity       ``(vx, vy, vz)`` [m/s] of the radar (scene frame)
    check_inside         raise if the radar sits inside closed geometry
    sampling             ``"random"`` (Monte Carlo rays, the default) or
                         ``"facets"``: one ray to the centroid of every
                         triangle in the cone, weighted by its solid angle
                         (a deterministic quadrature; with
                         ``triangle_average`` the exact per-facet physical
                         optics of PO codes); ``num_rays`` is then unused.
                         A facet too large for a linear phase across it
                         (``k D^2 / R >= facet_fresnel``, ``D`` its longest
                         edge, ``R`` its range) is split into ``n^2``
                         congruent sub-facets, each one ray and one exact
                         triangle average, so the quadrature converges in
                         the near field of large flat surfaces. Coherent
                         chains then continue deterministically (no
                         specular / scatter choice, no roulette); scattered
                         energy reaches the Tx by next-event estimation at
                         each interaction (scatter-then-scatter chains are
                         left out)
    facet_fresnel        bound on the quadratic phase ``k D^2 / R`` [rad] of a
                         (sub-)facet in ``"facets"`` sampling (default 0.5)
    max_facet_split      most splits ``n`` per facet edge (default 64)
    min_rel_power        drop paths weaker than this x the strongest (power
                         at the first Tx-Rx pair) before the per-element legs
                         are formed, in ``[0, 1)`` (default 0: keep all)
    triangle_average     integrate the physical-optics phase exactly over
                         each hit triangle (:mod:`.triangle_po`; variance
                         reduction, default on)
    diffraction          free-space diffraction (FSD, Steinberg et al. 2024;
                         :mod:`sionna_mmir.bsdf.fsd`) at interactions near
                         boundary / crease edges: with probability ``beta``
                         (the FSD diffracted fraction, scaled by the Fresnel
                         energy gate as edge opacity) the ray is diffracted
                         into a sampled forward direction and continues as a
                         power (incoherent) path
    fsd_width            Gaussian beam footprint ``s`` of the FSD lobe [m]
                         (default 3 wavelengths)
    reciprocal           add the reversed twin of every path whose
                         receiver-side chain is specular and whose last
                         event scatters (scatter first, mirror last: the
                         Tx-side specular connection), by reciprocity
    samples              ``paths.samples`` of an earlier call: replay its
                         discrete decisions (hit triangles, barycentrics)
                         instead of tracing -- frozen samples, e.g. for
                         finite-difference checks of the AD gradients
    returns              :class:`~sionna_mmir.paths.RadarPaths`
    ===================  =====================================================
    """

    def __init__(self, deterministic: bool = True):
        super().__init__(deterministic=deterministic)

    # ------------------------------------------------------------------ public
    def __call__(self, scene, radar=None, *, num_rays: int = 20000, max_depth: int = 3,
                 seed: int = 0, cone_angle_deg: float = 90.0, coherent: bool = True,
                 scattering: bool = True, tx_pattern="cos", rx_pattern="cos",
                 rr_depth: int = 2, velocities: dict | None = None, radar_velocity=None,
                 check_inside: bool = True, samples=None, reciprocal: bool = True,
                 diffraction: bool = False, fsd_width: float | None = None,
                 triangle_average: bool = True, sampling: str = "random",
                 facet_fresnel: float = 0.5, max_facet_split: int = 64,
                 min_rel_power: float = 0.0) -> RadarPaths:
        radar = _radar_of(scene, radar)
        self._check_args(scene, num_rays, max_depth, seed, cone_angle_deg, velocities)
        if isinstance(min_rel_power, bool) or not (
                isinstance(min_rel_power, (int, float, np.floating))
                and np.isfinite(min_rel_power) and 0.0 <= float(min_rel_power) < 1.0):
            raise ConfigError(f"min_rel_power must be in [0, 1), got {min_rel_power!r}")
        geo = SceneGeometry(scene)
        geo.validate()
        if samples is not None:
            geo.replay = list(samples[0])
            tape = Tape(samples[1])
        else:
            geo.record = []
            tape = Tape()
        pose = Pose.from_tensors(scene.position, scene.orientation)
        ptx, prx = _patterns(tx_pattern, rx_pattern, radar)
        wavelength = SPEED_OF_LIGHT / float(dr.detach(scene.frequency)[0]) \
            if dr.width(scene.frequency) else radar.wavelength
        frequency = SPEED_OF_LIGHT / wavelength
        T, R = radar.num_tx, radar.num_rx
        centre_local = np.concatenate([radar.tx_positions, radar.rx_positions]).mean(axis=0)
        c_w = pose.point(centre_local)
        tx_w = pose.point(radar.tx_positions)
        rx_w = pose.point(radar.rx_positions)
        if check_inside and samples is None:
            self._check_inside(geo, dr.detach(c_w))

        # -------- candidate rays (shared seed; no AD)
        if sampling == "facets":
            if not (np.isfinite(facet_fresnel) and facet_fresnel > 0) or int(max_facet_split) < 1:
                raise ConfigError(f"facet_fresnel must be > 0 and max_facet_split >= 1, got "
                                  f"{facet_fresnel!r}, {max_facet_split!r}")
            k_w = 2.0 * math.pi / wavelength
            origin, d_scene, pdf, target, sub_uv = self._facet_rays(
                geo, pose, dr.detach(c_w), cone_angle_deg, k_w, float(facet_fresnel),
                int(max_facet_split))
            N = dr.width(pdf)
            if N == 0:
                return self._empty(T, R, 0)
        elif sampling == "random":
            N = int(num_rays)
            # opaque seeds: a literal would be baked into the kernels and every new
            # seed (every fit iteration) would recompile them (~1 s per iteration)
            sampler = mi.PCG32(size=N, initstate=dr.opaque(mi.UInt64, int(seed)))
            u1, u2 = sampler.next_float32(), sampler.next_float32()
            local, pdf = cone_directions(u1, u2, math.radians(cone_angle_deg))
            d_radar = mi.Vector3f(local.z, local.x, local.y)        # +z_local -> boresight +x
            with dr.suspend_grad():
                d_scene = pose.to_scene(d_radar)
                origin = dr.zeros(mi.Point3f, N) + dr.detach(c_w)
        else:
            raise ConfigError(f"sampling must be 'random' or 'facets', got {sampling!r}")
        valid, obj, face, u, v = geo.trace(origin, d_scene)
        if sampling == "facets":             # keep rays that reach their own facet
            valid &= tape.freeze(face == target)
        keep = dr.compress(valid)
        K = dr.width(keep)
        if K == 0:
            return self._empty(T, R, N)
        pdf = tape.freeze(dr.gather(mi.Float, pdf, keep))
        obj, face = dr.gather(mi.UInt32, obj, keep), dr.gather(mi.UInt32, face, keep)
        u, v = dr.gather(mi.Float, u, keep), dr.gather(mi.Float, v, keep)
        n_est = 1 if sampling == "facets" else N
        valid = dr.full(mi.Bool, True, K)
        rng = mi.PCG32(size=K, initstate=dr.opaque(mi.UInt64, int(seed) + 0x9E3779B9))

        # -------- path state (width K)
        it = geo.interaction(valid, obj, face, u, v, tape)
        if sampling == "facets":
            # the first interaction integrates over its sub-facet, not the whole facet
            uv = [dr.gather(mi.Float, c, keep) for c in sub_uv]
            P0, P1, P2 = it.tri
            e1, e2 = P1 - P0, P2 - P0
            it.tri = tuple(P0 + e1 * uv[2 * c] + e2 * uv[2 * c + 1] for c in range(3))
        x1 = it.p
        cw_k = dr.zeros(mi.Point3f, K) + c_w
        k0 = dr.normalize(x1 - cw_k)
        L0_det = tape.freeze(dr.norm(x1 - cw_k))
        e_r = pose.to_scene(prx.polarization(pose.to_radar(k0)))
        E = Field(transverse(e_r, k0))
        inv_p = dr.ones(mi.Float, K)            # 1 / prob(coherent chain so far)
        coh = dr.full(mi.Bool, True, K)         # still a specular (coherent) chain
        beta = dr.zeros(mi.Float, K)            # incoherent throughput (* L0^2)
        p_area = dr.zeros(mi.Float, K)          # area density of the current x (coherent)
        chain = dr.zeros(mi.Float, K)           # x_1 -> x_l length (AD)
        prev_p = cw_k
        pending = None                          # deferred BSDF-sampling weight
        rate_chain = dr.zeros(mi.Float, K)
        vel = self._velocity_table(geo, velocities)
        v_radar = mi.Vector3f(*(float(c) for c in (np.asarray(radar_velocity, dtype=float).reshape(3)
                                                   if radar_velocity is not None else np.zeros(3))))
        first_pdf = pdf
        fsd_state = self._fsd_setup(geo, wavelength, fsd_width) if diffraction else None
        # coherent chains are integrated over the first surface (image theory): the
        # Tx leg of a mirror chain x1 -> x2 .. xl -> Tx is |M(x1) - Tx| with M the
        # chain's mirrors (M_l o .. o M_2), x_img = M(x1), Lm = linear part of M
        tri1 = it.tri
        x_img = x1
        Lm = [mi.Vector3f(1.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0), mi.Vector3f(0.0, 0.0, 1.0)]

        outs = []
        for depth in range(1, int(max_depth) + 1):
            # dead lanes get a harmless dummy point 1 m ahead (no NaN anywhere)
            x = dr.select(it.valid, it.p, prev_p + mi.Vector3f(1.0, 0.0, 0.0))
            n_sh = dr.select(it.valid, it.n, mi.Vector3f(-1.0, 0.0, 0.0))
            it.ng = dr.select(it.valid, it.ng, mi.Vector3f(-1.0, 0.0, 0.0))
            k_in = dr.normalize(x - prev_p)
            seg = dr.maximum(dr.norm(x - prev_p), 1e-6)
            if depth > 1:
                chain = chain + seg
            n = dr.select(dr.dot(k_in, n_sh) > 0, -n_sh, n_sh)
            cos_in = dr.maximum(-dr.dot(k_in, n), 0.0)
            front = dr.dot(k_in, it.ng) < 0
            ng = dr.select(front, it.ng, -it.ng)
            if depth == 1:
                p_area = tape.freeze(first_pdf * dr.abs(dr.dot(k_in, ng)) / dr.square(L0_det))
            # deferred weight of a BSDF-sampled direction that led here (area measure)
            if pending is not None:
                pw, pf_n, pf_params, pf_wi, pf_pdf, pf_mask = pending
                wo_prev = mi.Frame3f(pf_n).to_local(k_in)
                f_prev = pf_params[1] * mmwave.eval(pf_wi, wo_prev, pf_params[0])
                g_ad = dr.maximum(wo_prev.z, 0.0) * dr.abs(dr.dot(k_in, ng)) / dr.square(seg)
                g_det = tape.freeze(pf_pdf * dr.abs(dr.dot(k_in, ng)) / dr.square(seg))
                w = f_prev * g_ad / dr.maximum(g_det, 1e-30) * it.area_ratio * pw
                beta = dr.select(pf_mask, beta * w, beta)
            # materials at x
            eps = complex_permittivity(it.mat[0], it.mat[1], backend="drjit")
            sigma_h, l_c, tau_b, thick = it.mat[2], it.mat[3], it.mat[4], it.mat[5]
            sc_in = slab_coefficients(cos_in, eps, thick, frequency, backend="drjit")
            k_wave = 2.0 * math.pi / wavelength

            # ---- connection to the transmitter (array centre for shared terms)
            to_c = c_w - x
            d_c = dr.norm(to_c)
            k_t = to_c / d_c
            cos_t = dr.dot(n, k_t)
            ok = it.valid & (cos_t > 0) & (dr.dot(ng, k_t) > 0) & (cos_in > 0)
            ok &= tape.freeze_call(geo.visible, x + ng * RAY_EPSILON, c_w, ok)
            cos_t = dr.maximum(cos_t, 0.0)
            if depth > 1:
                # unfold the chain: image of x1 in this interaction's plane
                x_img = x_img - n * (2.0 * dr.dot(x_img - x, n))
                Lm = [c - n * (2.0 * dr.dot(c, n)) for c in Lm]
            e_t = transverse(pose.to_scene(ptx.polarization(pose.to_radar(-k_t))), k_t)
            rate = self._rate(rate_chain, vel, it.obj, k_in, k_t, v_radar, k0)
            C_re = dr.zeros(mi.Float, K)
            C_im = dr.zeros(mi.Float, K)
            if coherent:
                E_ref = reflect_field(E, k_in, n, sc_in.r_s, sc_in.r_p)
                pr, pi_ = E_ref.dot(e_t)
                eta_b = dr.exp(-dr.square(k_wave * sigma_h * (cos_in + cos_t)))
                scale = (0.5 * (cos_in + cos_t) * dr.sqrt(eta_b) * inv_p * it.area_ratio
                         / (4.0 * math.pi * dr.maximum(p_area, 1e-30) * n_est))
                m = ok & coh
                wr, wi = -pi_ * scale, pr * scale            # j * (pr + j pi)
                # Tx-side distance of the unfolded chain and the phase gradient
                # on the first surface: grad_y (|y - c| + |M(y) - c|) at x1
                to_img = x_img - cw_k
                d_img = dr.norm(to_img)
                if triangle_average:
                    u_img = to_img / dr.maximum(d_img, 1e-9)
                    g_img = mi.Vector3f(*(dr.dot(c, u_img) for c in Lm))     # Lm^T u
                    fr, fi = triangle_phase_average(k_wave * (k0 + g_img), *tri1, x1)
                    # only where the phase is linear across the triangle: the
                    # quadratic (Fresnel) term k D^2 / R must stay below ~1 rad
                    P0, P1, P2 = (dr.detach(v) for v in tri1)
                    D2 = dr.maximum(dr.maximum(dr.squared_norm(P1 - P0), dr.squared_norm(P2 - P0)),
                                    dr.squared_norm(P2 - P1))
                    near = dr.minimum(dr.detach(d_img), L0_det)
                    lin = tape.freeze(k_wave * D2 / dr.maximum(near, 1e-3) < 1.0)
                    fr, fi = dr.select(lin, fr, 1.0), dr.select(lin, fi, 0.0)
                    wr, wi = wr * fr - wi * fi, wr * fi + wi * fr
                if depth == 1:
                    C_re += dr.select(m, wr, 0.0)
                    C_im += dr.select(m, wi, 0.0)
                else:
                    # a separate path: Tx leg from the unfolded image of x1, no chain
                    zero = dr.zeros(mi.Float, K)
                    outs.append((dr.select(m, wr, 0.0), dr.select(m, wi, 0.0), x_img, x1, zero,
                                 zero, rate, depth, m))
            if scattering:
                fs, fp = polarization_fractions(E, k_in, n)
                sc_t = slab_coefficients(cos_t, eps, thick, frequency, backend="drjit")
                gate = fs * dr.squared_norm(sc_t.r_s) + fp * dr.squared_norm(sc_t.r_p)
                params = mmwave.MMWaveParams(sigma_h, l_c, tau_b, wavelength, gate)
                frame = mi.Frame3f(n)
                wi_t, wo_r = frame.to_local(k_t), frame.to_local(-k_in)
                eta_t = params.eta(dr.maximum(cos_t, 0.0))
                f_sc = (1.0 - eta_t) * mmwave.eval(wi_t, wo_r, params)
                base = dr.select(coh, E.power() * inv_p * cos_in * it.area_ratio
                                 / (dr.maximum(p_area, 1e-30) * n_est), beta)
                P = dr.square(wavelength / (4.0 * math.pi)) * f_sc * cos_t * base
                amp = dr.select(ok, dr.sqrt(dr.maximum(P, 1e-36)), 0.0)
                phase = 2.0 * math.pi * rng.next_float32()
                sc_re, sc_im = amp * dr.cos(phase), amp * dr.sin(phase)
                C_re += sc_re
                C_im += sc_im
            zero = dr.zeros(mi.Float, K)
            if depth == 1 or scattering:      # (deeper coherent terms were added above)
                outs.append((C_re, C_im, x, x1, zero, chain, rate, depth, ok))
            if scattering and reciprocal and depth > 1:
                # the reversed path (scatter at x first, then the specular chain to
                # the Tx) is not sampled from the Rx side: add it by reciprocity
                m = coh & ok
                outs.append((dr.select(m, sc_re, 0.0), dr.select(m, sc_im, 0.0), x1, x, chain,
                             zero, rate, depth, m))

            if depth == int(max_depth):
                break
            # ---- continuation: mirror (coherent) or BSDF sample (incoherent)
            eta_in = dr.exp(-dr.square(2.0 * k_wave * sigma_h * cos_in))
            p_spec = tape.freeze(eta_in) if scattering else dr.ones(mi.Float, K)
            if sampling == "facets":
                # deterministic quadrature: coherent chains always continue (their
                # field carries sqrt(eta)); a random specular/scatter choice would
                # thin the first-surface integral at random (variance ~ the sum of
                # |terms|^2, which dwarfs the stationary-phase sum). The scattered
                # energy still reaches the Tx by next-event estimation at every
                # interaction; scatter-then-scatter chains are left out.
                p_spec = dr.ones(mi.Float, K)
            if not coherent:
                p_spec = dr.zeros(mi.Float, K)
            u_ev = rng.next_float32()
            live = it.valid
            if diffraction:
                diff, k_diff = self._diffract(fsd_state, x, k_in, gate_fsd(E, k_in, n, sc_in),
                                              wavelength, rng, tape, it.valid)
                live = it.valid & ~diff
            spec = live & (u_ev < p_spec)
            scat = live & ~spec & scattering
            # specular branch
            k_mir = mirror(k_in, n)
            E_new = reflect_field(E, k_in, n, sc_in.r_s, sc_in.r_p).scale(dr.sqrt(eta_in))
            pol_pow = E_new.power() / dr.maximum(E.power(), 1e-30)
            # scattered branch: sample the BSDF in the local frame around the mirror
            frame = mi.Frame3f(n)
            wi_loc = frame.to_local(-k_in)
            fs, fp = polarization_fractions(E, k_in, n)
            gate_in = fs * dr.squared_norm(sc_in.r_s) + fp * dr.squared_norm(sc_in.r_p)
            params_in = mmwave.MMWaveParams(sigma_h, l_c, tau_b, wavelength, gate_in)
            with dr.suspend_grad():
                wo_s, pdf_s = mmwave.sample(dr.detach(wi_loc), rng.next_float32(),
                                            mi.Point2f(rng.next_float32(), rng.next_float32()),
                                            params_in)
                k_sc = frame.to_world(wo_s)
                ok_s = tape.freeze(scat & (wo_s.z > 1e-4) & (pdf_s > 0))
                pdf_s = tape.freeze(pdf_s)
            # become incoherent: fold the coherent chain's power into beta
            base_coh = E.power() * inv_p * cos_in * it.area_ratio / (dr.maximum(p_area, 1e-30) * n_est)
            beta = dr.select(scat & coh, base_coh, beta)
            if diffraction:
                # diffracted lanes carry their power on (eval / (pdf * beta) = 1)
                beta = dr.select(diff & coh, base_coh, beta)
            beta = dr.select(spec & ~coh, beta * pol_pow / dr.maximum(p_spec, 1e-6), beta)
            pending = ((1.0 - eta_in) / dr.maximum(1.0 - p_spec, 1e-6),
                       n, (params_in, 1.0), wi_loc, dr.detach(pdf_s), ok_s)
            inv_p = dr.select(spec & coh, inv_p / dr.maximum(p_spec, 1e-6), inv_p)
            E = E_new.select(spec, E)
            coh = coh & spec
            # Russian roulette on the power-carrying paths
            alive = spec | ok_s
            if diffraction:
                alive |= diff
            if depth + 1 > rr_depth:
                q = tape.freeze(dr.clip(dr.select(coh, pol_pow, 0.5), 0.1, 1.0))
                if sampling == "facets":
                    q = dr.select(coh, 1.0, q)     # no roulette on the quadrature's chains
                survive = rng.next_float32() < q
                alive &= survive
                inv_p = dr.select(coh, inv_p / q, inv_p)
                beta = dr.select(~coh, beta / q, beta)
            k_next = dr.select(spec, k_mir, k_sc)
            if diffraction:
                coh = coh & ~diff
                k_next = dr.select(diff, k_diff, k_next)
            # trace the next segment (detached), rebuild in AD
            with dr.suspend_grad():
                side = dr.select(dr.dot(dr.detach(k_next), dr.detach(ng)) > 0, 1.0, -1.0)
                o2 = dr.detach(x) + dr.detach(ng) * (RAY_EPSILON * side)
                if diffraction:       # free-space diffraction passes the surface
                    o2 = dr.select(diff, dr.detach(x) + dr.detach(k_next) * 1e-3, o2)
                v2, ob2, fa2, uu, vv = geo.trace(o2, dr.detach(k_next), alive)
            # motion along the chain: vertex x moving with v contributes v.(u_in + u_out)
            rate_chain = rate_chain + self._vertex_rate(vel, it.obj, k_in, -k_next)
            prev_p = x
            it = geo.interaction(v2, ob2, fa2, uu, vv, tape)
            # area density of the next point for coherent chains: p_A = rho cos / L_unf^2
            L_unf = tape.freeze(L0_det + chain + dr.norm(it.p - x))
            cos_next = tape.freeze(dr.select(v2, dr.abs(dr.dot(dr.normalize(it.p - x), it.ng)), 0.0))
            p_area = dr.select(coh, first_pdf * cos_next / dr.square(L_unf), p_area)
            it.valid = it.valid & v2

        paths = self._assemble(outs, radar, pose, geo, ptx, prx, tx_w, rx_w, x1, N, K,
                               velocities is not None or radar_velocity is not None,
                               float(min_rel_power))
        paths.samples = samples if samples is not None else (geo.record, tape.values)
        return paths

    # ---------------------------------------------------------------- facets
    @staticmethod
    def _facet_rays(geo, pose, centre, cone_angle_deg, k_wave, fresnel, max_split):
        """Rays from the array centre to every (sub-)facet centroid inside the cone.

        A facet whose quadratic phase ``k D^2 / R`` (``D`` longest edge, ``R``
        range of its nearest vertex) reaches ``fresnel`` is split into ``n^2``
        congruent sub-triangles, ``n = ceil(sqrt(k D^2 / (R fresnel)))``
        (at most ``max_split``): the ``n (n + 1) / 2`` upright and
        ``n (n - 1) / 2`` inverted cells of the barycentric grid of step
        ``1 / n``.

        Returns ``(origin, direction, pdf, face, sub_uv)`` with ``pdf = 1 /
        Omega_s``, ``Omega_s = (A_t / n^2) |cos| / d^2`` the sub-facet's solid
        angle (so the estimator's area density is ``1 / A_s``: a quadrature
        weight) and ``sub_uv`` six ``mi.Float`` (``u, v`` of the sub-facet's
        three corners in the facet's barycentric coordinates).
        """
        V = np.asarray(dr.detach(geo.positions), dtype=np.float64).reshape(-1, 3)
        F = np.asarray(geo.faces, dtype=np.int64).reshape(-1, 3)
        p0, p1, p2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        cen = (p0 + p1 + p2) / 3.0
        cr = np.cross(p1 - p0, p2 - p0)
        area = 0.5 * np.linalg.norm(cr, axis=1)
        nrm = cr / np.maximum(2 * area, 1e-30)[:, None]
        c = np.array([float(centre[i][0]) for i in range(3)])
        d = cen - c
        dist = np.linalg.norm(d, axis=1)
        d /= np.maximum(dist, 1e-12)[:, None]
        rows = np.array([[float(r[i][0]) for i in range(3)] for r in pose.rows])
        bore = rows[:, 0]                                     # radar +x in the scene
        cos_b = d @ bore
        cos_n = np.abs(np.sum(d * nrm, axis=1))
        ok = (cos_b >= np.cos(np.radians(cone_angle_deg)) - 1e-9) & (cos_n > 1e-4) & (dist > 1e-3)
        idx = np.flatnonzero(ok)
        # splits per facet from its quadratic phase at its nearest vertex
        D2 = np.max(np.stack([np.sum((p1 - p0) ** 2, 1), np.sum((p2 - p0) ** 2, 1),
                              np.sum((p2 - p1) ** 2, 1)]), axis=0)[idx]
        near = np.min(np.stack([np.linalg.norm(p - c, axis=1)[idx] for p in (p0, p1, p2)]), axis=0)
        n_split = np.clip(np.ceil(np.sqrt(k_wave * D2 / (np.maximum(near, 1e-3) * fresnel))),
                          1, max_split).astype(np.int64)
        fac, uvs, ns = [], [], []
        for n in np.unique(n_split):
            sel = idx[n_split == n]
            cells = _subfacet_cells(int(n))                  # [n^2, 3, 2] corner (u, v)
            fac.append(np.repeat(sel, len(cells)))
            uvs.append(np.tile(cells, (len(sel), 1, 1)))
            ns.append(np.full(len(sel) * len(cells), float(n)))
        fac = np.concatenate(fac) if fac else np.zeros(0, np.int64)
        uvs = np.concatenate(uvs) if uvs else np.zeros((0, 3, 2))
        ns = np.concatenate(ns) if ns else np.zeros(0)
        cu, cv = uvs[:, :, 0].mean(1), uvs[:, :, 1].mean(1)
        q = p0[fac] + cu[:, None] * (p1 - p0)[fac] + cv[:, None] * (p2 - p0)[fac]
        dq = q - c
        dq_n = np.linalg.norm(dq, axis=1)
        dq /= np.maximum(dq_n, 1e-12)[:, None]
        cos_q = np.maximum(np.abs(np.sum(dq * nrm[fac], axis=1)), 1e-6)
        omega = area[fac] / ns ** 2 * cos_q / np.maximum(dq_n, 1e-3) ** 2
        n = len(fac)
        dd = dq.astype(np.float32)
        origin = mi.Point3f(*(dr.full(mi.Float, float(v), n) for v in c))   # n may be 0
        direction = mi.Vector3f(mi.Float(dd[:, 0]), mi.Float(dd[:, 1]), mi.Float(dd[:, 2]))
        sub_uv = [mi.Float(uvs[:, k, j].astype(np.float32)) for k in range(3) for j in range(2)]
        return (origin, direction, mi.Float((1.0 / omega).astype(np.float32)),
                mi.UInt32(fac.astype(np.uint32)), sub_uv)

    # ------------------------------------------------------------- diffraction
    @staticmethod
    def _fsd_setup(geo, wavelength, width):
        from ..scene.edges import EdgeIndex, find_diffracting_edges

        verts = np.asarray(dr.detach(geo.positions), dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(geo.faces, dtype=np.int64).reshape(-1, 3)
        es = find_diffracting_edges(verts, faces)
        s = float(width) if width is not None else 3.0 * wavelength
        return {"edges": es, "index": EdgeIndex(es) if len(es) else None, "s": s,
                "radius": 3.0 * s}

    @staticmethod
    def _diffract(state, x, k_in, opacity, wavelength, rng, tape, valid):
        """``(mask, direction)`` of lanes diffracted by nearby edges (FSD).

        Detached: edge diffraction redirects power but passes no gradient.
        """
        from ..bsdf import fsd

        n = dr.width(valid)
        u_d, u1, u2, u3 = (rng.next_float32() for _ in range(4))
        if state["index"] is None:
            return tape.freeze(dr.zeros(mi.Bool, n)), dr.zeros(mi.Vector3f, n)
        xs = np.column_stack([np.asarray(dr.detach(x[c]), dtype=np.float64) for c in range(3)])
        idx, ok = state["index"].query(xs, state["radius"], max_edges=4)
        ok &= np.asarray(valid, dtype=bool)[:, None]
        es = state["edges"]
        sel = [getattr(es, name)[idx.ravel()].reshape(idx.shape + (3,))
               for name in ("p0", "p1", "apex0", "apex1")]
        edges = fsd.FsdEdges.from_numpy(*sel, valid=ok)
        with dr.suspend_grad():
            d, xd = dr.detach(k_in), dr.detach(x)
            p_d = tape.freeze(fsd.beta(d, xd, edges, wavelength, state["s"],
                                       opacity=dr.detach(opacity), check=False))
            wo, pdf = fsd.sample(d, xd, edges, wavelength, state["s"], u1, mi.Point2f(u2, u3),
                                 check=False)
            mask = tape.freeze(valid & (u_d < p_d) & (pdf > 0))
        return mask, wo

    # --------------------------------------------------------------- internals
    @staticmethod
    def _check_args(scene, num_rays, max_depth, seed, cone_angle_deg, velocities):
        if not hasattr(scene, "mesh_objects"):
            raise ConfigError("RadarPathSolver needs a sionna_mmir RadarScene (sionna_mmir.load_scene)")
        if int(num_rays) < 1:
            raise ConfigError(f"num_rays must be >= 1, got {num_rays}")
        if int(max_depth) < 1:
            raise ConfigError(f"max_depth must be >= 1, got {max_depth}")
        if int(seed) < 0:
            raise ConfigError(f"seed must be >= 0, got {seed}")
        if not 0 < float(cone_angle_deg) <= 90:
            raise ConfigError(f"cone_angle_deg must be in (0, 90], got {cone_angle_deg}")
        for name in (velocities or {}):
            if name not in scene.mesh_objects:
                raise ConfigError(f"velocities: unknown object {name!r}")

    @staticmethod
    def _check_inside(geo, c):
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

    @staticmethod
    def _velocity_table(geo, velocities):
        if not velocities:
            return None
        table = np.zeros((len(geo.names), 3), dtype=np.float32)
        for i, name in enumerate(geo.names):
            if name in velocities:
                vv = np.asarray(velocities[name], dtype=np.float64).reshape(-1)
                if vv.shape != (3,) or not np.isfinite(vv).all():
                    raise InputValueError(f"velocities[{name!r}] must be 3 finite numbers [m/s]")
                table[i] = vv
        return [mi.Float(table[:, c]) for c in range(3)]

    @staticmethod
    def _vertex_rate(vel, obj, u_in, u_out):
        if vel is None:
            return dr.zeros(mi.Float, dr.width(obj))
        v = mi.Vector3f(*(dr.gather(mi.Float, vel[c], obj) for c in range(3)))
        # dL/dx for the two adjacent segments: unit(x - prev) + unit(x - next)
        return dr.detach(dr.dot(v, u_in - u_out))

    def _rate(self, rate_chain, vel, obj, k_in, k_t, v_radar, k0):
        r = rate_chain + self._vertex_rate(vel, obj, k_in, k_t)
        # moving radar: both end legs shorten by v . direction to the scene
        r = r - dr.detach(dr.dot(v_radar, k0) + dr.dot(v_radar, -k_t))
        return r / SPEED_OF_LIGHT

    def _strong(self, C_re, C_im, X, X1, chain_t, chain, tx_w, rx_w, ptx, prx, pose, P,
                min_rel_power) -> np.ndarray:
        """Indices (sorted) of the paths whose power at the first Tx-Rx pair,
        ``|C|^2 g_t0^2 g_r0^2``, exceeds ``min_rel_power`` x the strongest's.

        The proxy costs two ``[P]`` legs instead of the ``[T, P] + [R, P]``
        the paths need; for an array a few cm wide at >= 1 m, element gains
        and leg lengths differ from the first element's by a small fraction
        of a dB, which only moves paths within that of the threshold
        (:meth:`PathFactors.pruned` uses the mean over all pairs).
        """
        with dr.suspend_grad():
            g_t, _ = self._leg(tx_w, dr.detach(X), dr.detach(chain_t), ptx, pose, 1, P)
            g_r, _ = self._leg(rx_w, dr.detach(X1), dr.detach(chain), prx, pose, 1, P)
            pw = (dr.square(dr.detach(C_re)) + dr.square(dr.detach(C_im))) \
                * dr.square(g_t) * dr.square(g_r)
            dr.eval(pw)
        pw = np.asarray(pw, dtype=np.float64)
        return np.flatnonzero(pw > min_rel_power * pw.max())

    @staticmethod
    def _leg(elements, X, chain, pattern, pose, n, P):
        """``(sqrt(G) / length, length)`` [n * P] of the element <-> ``X`` legs.

        ``length = |X - element| + chain`` (the unfolded length on that side);
        the gain is the element's pattern towards ``X`` in the radar frame.
        """
        i = dr.arange(mi.UInt32, n * P)
        Pv = dr.opaque(mi.UInt32, P)          # a literal P would recompile per path count
        e_idx = i // Pv
        p_idx = i - e_idx * Pv
        e = _gather3(elements, e_idx)
        xp = _gather3(X, p_idx)
        d = dr.maximum(dr.norm(xp - e), 1e-6)
        length = d + dr.gather(mi.Float, chain, p_idx)
        return dr.sqrt(pattern.gain(pose.to_radar((xp - e) / d), e_idx)) / length, length

    @staticmethod
    def _empty(T, R, N):
        z = dr.zeros(mi.Float, 0)
        return RadarPaths(a_re=z, a_im=z, tau=z, tau_rate=None, shape=(T, R, 0),
                          depth=np.zeros(0, dtype=np.int32), num_candidates=N,
                          info={"hits": 0})

    def _assemble(self, outs, radar, pose, geo, ptx, prx, tx_w, rx_w, x1, N, K, moving,
                  min_rel_power=0.0):
        """Per-path terms and per-element legs as factorised :class:`RadarPaths`.

        With ``min_rel_power > 0`` the paths weaker than that x the strongest
        at the first Tx-Rx pair (:meth:`_strong`) are dropped *before* the
        per-element legs (``[T, P]``, ``[R, P]``) are formed.
        """
        T, R = radar.num_tx, radar.num_rx
        # keep only lanes that contribute (connected to the Tx): dead rays, failed
        # shadow rays and empty reciprocal twins are dropped before the per-element
        # legs are formed (the masks are detached and frozen, so replay is identical)
        # evaluate every per-depth term in one pass: compress and gather would
        # otherwise evaluate each field (and the shared upstream work) in a
        # kernel of its own (values and the AD graph are unchanged)
        dr.eval(*(f for o in outs for f in o[:7]), *(o[8] for o in outs))
        kept = []
        for o in outs:
            idx = dr.compress(dr.detach(o[8]))
            if dr.width(idx) == 0:
                continue
            g = []
            for i, f in enumerate(o[:7]):
                if i in (2, 3):
                    g.append(_gather3(f, idx))
                else:
                    g.append(dr.gather(mi.Float, f, idx))
            kept.append(tuple(g) + (o[7], dr.width(idx)))
        if not kept:
            return self._empty(T, R, N)
        outs = kept
        P = sum(o[8] for o in outs)

        def cat(i):
            return dr.concat([o[i] for o in outs]) if len(outs) > 1 else outs[0][i]

        def cat3(i):
            return mi.Point3f(*(cat_c(i, c) for c in range(3)))

        def cat_c(i, c):
            return dr.concat([o[i][c] for o in outs]) if len(outs) > 1 else outs[0][i][c]

        C_re, C_im = cat(0), cat(1)
        X, X1 = cat3(2), cat3(3)           # Tx-leg and Rx-leg interaction points
        chain_t, chain = cat(4), cat(5)    # chain lengths on the Tx / Rx side
        rate = cat(6)
        depth = np.concatenate([np.full(o[8], o[7], dtype=np.int32) for o in outs])
        if min_rel_power > 0.0:
            keep = self._strong(C_re, C_im, X, X1, chain_t, chain, tx_w, rx_w, ptx, prx,
                                pose, P, min_rel_power)
            if keep.size < P:
                idx = mi.UInt32(keep.astype(np.uint32))
                C_re, C_im = dr.gather(mi.Float, C_re, idx), dr.gather(mi.Float, C_im, idx)
                X, X1 = _gather3(X, idx), _gather3(X1, idx)
                chain_t, chain = dr.gather(mi.Float, chain_t, idx), dr.gather(mi.Float, chain, idx)
                rate = dr.gather(mi.Float, rate, idx)
                depth, P = depth[keep], int(keep.size)
        # per-Tx leg [T, P] and per-Rx leg [R, P]: sqrt(gain) / leg length, and lengths
        g_t, dt = self._leg(tx_w, X, chain_t, ptx, pose, T, P)
        g_r, L = self._leg(rx_w, X1, chain, prx, pose, R, P)
        # factorised [T, R, P]: a = conj(C) g_t g_r (FMCW beat convention, see
        # fmcw.model), tau = (dt + L) / c; expanded only on demand (RadarPaths)
        factors = PathFactors(c_re=C_re, c_im=-C_im, g_t=g_t, tau_t=dt / SPEED_OF_LIGHT,
                              g_r=g_r, tau_r=L / SPEED_OF_LIGHT, rate=rate if moving else None,
                              shape=(T, R, P))
        return RadarPaths.from_factors(factors, depth=depth, num_candidates=N, info={"hits": K})


def _subfacet_cells(n: int) -> np.ndarray:
    """Corners ``[n^2, 3, 2]`` (barycentric ``u, v``) of the ``n^2`` congruent
    sub-triangles of a triangle split ``n`` times per edge (same winding)."""
    out = []
    for i in range(n):
        for j in range(n - i):
            out.append([(i, j), (i + 1, j), (i, j + 1)])
            if i + j < n - 1:
                out.append([(i + 1, j), (i + 1, j + 1), (i, j + 1)])
    return np.asarray(out, dtype=np.float64) / n
