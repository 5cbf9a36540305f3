"""State shared by the transport stages of one solver call.

:class:`SolverContext` holds what is constant during a call (options,
geometry, tape, pose, patterns, wavelength, element positions);
:class:`PathState` what every lane carries from one interaction to the next;
:class:`Surface` the local quantities at the current interaction; and
:class:`Emission` one group of paths handed to the assembly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ...utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

#: offset of secondary ray origins along the geometric normal [m]
RAY_EPSILON = 1e-4


@dataclass
class SolverContext:
    """Constants of one solver call.

    Parameters
    ----------
    options : SolverOptions
        The validated options.
    geo : SceneGeometry
        Differentiable mesh arrays of the scene.
    tape : Tape
        Frozen detached values (record or replay).
    pose : Pose
        Radar pose (Dr.Jit, AD).
    ptx, prx : BeamPattern
        Tx and Rx element patterns.
    wavelength, frequency : float
        Carrier wavelength [m] and frequency [Hz].
    c_w : mi.Point3f
        Array phase centre in the scene [m].
    tx_w, rx_w : mi.Point3f
        Tx / Rx element positions in the scene [m].
    num_tx, num_rx : int
        Element counts.
    sampler : RandomCone or FacetQuadrature
        Candidate-ray strategy.
    velocities : list of mi.Float or None
        Per-object velocity table (three components) [m/s].
    v_radar : mi.Vector3f
        Radar velocity [m/s].
    fsd : dict or None
        Free-space diffraction state (edges, index, width).
    """

    options: object
    geo: object
    tape: object
    pose: object
    ptx: object
    prx: object
    wavelength: float
    frequency: float
    c_w: object
    tx_w: object
    rx_w: object
    num_tx: int
    num_rx: int
    sampler: object
    velocities: object = None
    v_radar: object = None
    fsd: object = None
    n_est: int = 1
    rng: object = None

    @property
    def k_wave(self) -> float:
        """Wavenumber ``2 pi / lambda`` [rad/m]."""
        return 2.0 * math.pi / self.wavelength


@dataclass
class PathState:
    """What each lane (width ``K``) carries between interactions.

    Parameters
    ----------
    it : Interaction
        The current interaction (rebuilt in AD).
    E : Field
        Jones-transported field of the specular chain (from the Rx side).
    inv_p : mi.Float
        ``1 / prob`` of the coherent chain so far.
    coh : mi.Bool
        The lane is still a specular (coherent) chain.
    beta : mi.Float
        Incoherent throughput (times ``L0^2``) after the chain scattered.
    p_area : mi.Float
        Area density of the current point for coherent chains [1/m^2].
    chain : mi.Float
        ``x_1 -> x_l`` length [m] (AD).
    prev_p : mi.Point3f
        The previous vertex (the array centre at depth 1).
    pending : tuple or None
        Deferred weight of a BSDF-sampled direction (area measure).
    rate_chain : mi.Float
        Delay rate accumulated along the chain (times ``c``).
    first_pdf : mi.Float
        Density of the first direction [1/sr].
    x1, k0, L0_det, cw_k : mi arrays
        First interaction, first direction, first length (frozen), centre.
    tri1 : tuple
        Region the first interaction integrates over (triangle or sub-facet).
    U : tuple
        ``(cols, off)``: the chain's mirrors before the current interaction,
        ``U(y) = sum_c cols[c] y_c + off`` (three ``mi.Vector3f`` columns and
        a ``mi.Vector3f``; ``U = M_1 .. M_{l-1}``, identity at depth 1, AD).
    x_star : mi.Point3f
        ``U(x_l)``: the current interaction unfolded to the receiver's side
        (the receiver's image sees it there) [m].
    plane : tuple or None
        ``(n, x)`` of the current interaction, folded into ``U`` at the next.
    obj1 : mi.UInt32
        Object of the first interaction.
    aperture : LitAperture or None
        Lit region of the facet quadrature's chains (``None`` for random rays).
    fan : tuple or None
        ``(main, lane, extra)``: the lit footprint of the facet node's cell on
        the current triangle as triangles with frozen barycentric corners,
        areas and cell shares -- one per lane (``main``, eight ``mi.Float``)
        plus the pieces of cut cells (``lane``, ``extra``); see
        :func:`.aperture.clip`.  ``None`` for random rays.
    lit : mi.Float or None
        Lit fraction of the node's cell for the current chain (``None``: 1).
    """

    it: object
    E: object
    inv_p: object
    coh: object
    beta: object
    p_area: object
    chain: object
    prev_p: object
    rate_chain: object
    first_pdf: object
    x1: object
    k0: object
    L0_det: object
    cw_k: object
    tri1: tuple
    U: tuple
    x_star: object
    obj1: object = None
    pending: tuple | None = None
    plane: tuple | None = None
    aperture: object = None
    fan: tuple | None = None
    lit: object = None

    @property
    def width(self) -> int:
        """Number of lanes ``K``."""
        return dr.width(self.inv_p)


@dataclass
class Surface:
    """Local quantities at the current interaction ``x_l``.

    Parameters
    ----------
    x : mi.Point3f
        Interaction point (a dummy point 1 m ahead on dead lanes) [m].
    n : mi.Vector3f
        Shading normal facing the incident ray.
    ng : mi.Vector3f
        Geometric normal facing the incident ray.
    k_in : mi.Vector3f
        Incident direction (unit).
    seg : mi.Float
        Length of the incident segment [m].
    cos_in : mi.Float
        ``-k_in . n`` clamped at 0.
    eps : tuple
        Complex relative permittivity (Dr.Jit complex).
    sigma_h, l_c, tau_b, thick : mi.Float
        RMS height [m], correlation length [m], KA/SPM blend, thickness [m].
    sc_in : SlabCoefficients
        Slab reflection coefficients at the incident angle.
    """

    x: object
    n: object
    ng: object
    k_in: object
    seg: object
    cos_in: object
    eps: object
    sigma_h: object
    l_c: object
    tau_b: object
    thick: object
    sc_in: object


@dataclass
class Connection:
    """The deterministic connection ``x_l -> Tx`` (array centre).

    Parameters
    ----------
    k_t : mi.Vector3f
        Unit direction towards the array centre.
    cos_t : mi.Float
        ``n . k_t`` clamped at 0.
    ok : mi.Bool
        Valid, facing and unobstructed (frozen visibility).
    e_t : mi.Vector3f
        Tx element polarisation, transverse to ``k_t``.
    rate : mi.Float
        Delay rate of the path [s/s].
    """

    k_t: object
    cos_t: object
    ok: object
    e_t: object
    rate: object


@dataclass
class Emission:
    """One group of paths for the assembly (all width ``K``).

    Parameters
    ----------
    c_re, c_im : mi.Float
        Per-path amplitude (channel convention, before the element legs).
    x_tx, x_rx : mi.Point3f
        Points the Tx and the Rx legs connect to [m].
    chain_tx, chain_rx : mi.Float
        Lengths added on the Tx and Rx sides [m].
    rate : mi.Float
        Delay rate [s/s].
    depth : int
        Interactions of these paths.
    mask : mi.Bool
        Lanes that contribute.
    obj : mi.UInt32
        Object of each path's first interaction (receiver side).
    """

    c_re: object
    c_im: object
    x_tx: object
    x_rx: object
    chain_tx: object
    chain_rx: object
    rate: object
    depth: int
    mask: object
    obj: object = None

    def fields(self) -> tuple:
        """The seven per-lane arrays, in the assembly's order."""
        return (self.c_re, self.c_im, self.x_tx, self.x_rx, self.chain_tx, self.chain_rx,
                self.rate)


def zeros(width: int):
    """``mi.Float`` zeros of ``width``."""
    return dr.zeros(mi.Float, width)


__all__ = ["RAY_EPSILON", "SolverContext", "PathState", "Surface", "Connection", "Emission",
           "zeros"]
