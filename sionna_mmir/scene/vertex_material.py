"""``VertexRadioMaterial``: a Sionna radio material with ITU-R P.2040 parameters per vertex.

Each object of a :class:`~sionna_mmir.scene.RadarScene` carries one of these
as its Sionna radio material, and it is the one home of the object's
per-vertex parameters ``[Nv, 6]`` (:data:`PARAMETERS`):

==============  ======================================================
``eps_real``    real relative permittivity ``eps'`` (>= 1)
``eps_imag``    loss ``eps''`` of ``eps' - j eps''``
``sigma_h``     RMS surface height [m]
``l_c``         surface correlation length [m]
``tau``         KA / SPM blend of the mmIR BSDF
``d``           slab thickness [m]
==============  ======================================================

The radar path solver reads the tensor directly (inside its AD graph).
Sionna RT's own solvers see a regular :class:`sionna.rt.RadioMaterial`:
at every interaction the parameters are interpolated barycentrically at the
hit point (from ``si.p`` and ``si.prim_index``) and mapped to Sionna's
material model -- relative permittivity ``eps'``, conductivity
``sigma = eps'' eps_0 omega``, thickness ``d`` and scattering coefficient
``S = sqrt(1 - exp(-(2 k sigma_h cos(theta_i))^2))`` (the Rayleigh split of
the reflected energy the mmIR model uses between its coherent and scattered
parts) -- before Sionna's ITU-R P.2040 slab equations run.  ``l_c`` and
``tau`` shape the mmIR BSDF lobe and have no counterpart in Sionna's
Lambertian scattering pattern.
"""
from __future__ import annotations

import math

import numpy as np

from ..radio_materials.itu_table import EPSILON_0
from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
from sionna.rt import RadioMaterial  # noqa: E402

#: names of the six per-vertex parameters, in tensor column order
PARAMETERS = ("eps_real", "eps_imag", "sigma_h", "l_c", "tau", "d")


class VertexRadioMaterial(RadioMaterial):
    """Sionna radio material of one object, per-vertex ITU-R P.2040 parameters.

    Parameters
    ----------
    name : str
        Unique material name (Sionna registers materials by name).
    label : str
        The material class the parameters started from (e.g. ``"concrete"``).
    vertex_parameters : mi.TensorXf
        ``[Nv, 6]`` parameters (:data:`PARAMETERS`), differentiable.
    faces : numpy.ndarray
        ``[F, 3]`` vertex indices of the object's triangles.

    Notes
    -----
    The scalar Sionna attributes (``relative_permittivity``,
    ``conductivity``, ``thickness``, ``scattering_coefficient``) hold the
    parameters' means at the scene frequency, for display; evaluations use
    the per-vertex values.  :meth:`bind` attaches the object whose vertex
    positions locate the hit points.
    """

    def __init__(self, name: str, label: str, vertex_parameters, faces: np.ndarray,
                 frequency: float = 77e9):
        p = np.asarray(vertex_parameters, dtype=np.float64).reshape(-1, 6)
        mean = p.mean(axis=0)
        super().__init__(name=name, thickness=float(max(mean[5], 0.0)),
                         relative_permittivity=float(max(mean[0], 1.0)),
                         conductivity=float(max(mean[1], 0.0)) * EPSILON_0
                         * 2.0 * math.pi * float(frequency))
        self.label = label
        self.vertex_parameters = vertex_parameters
        self._faces = mi.UInt32(np.ascontiguousarray(faces, dtype=np.uint32).ravel())
        self._object = None

    def bind(self, obj) -> None:
        """Attach the scene object (its ``vertex_positions`` locate hits)."""
        self._object = obj

    # ----------------------------------------------------- per-lane parameters
    def parameters_at(self, p, prim_index):
        """The six parameters interpolated at points ``p`` on triangles ``prim_index``.

        Parameters
        ----------
        p : mi.Point3f
            Points on the object's surface [m].
        prim_index : mi.UInt32
            Triangle of each point (object-local index).

        Returns
        -------
        list of mi.Float
            The six parameters, barycentrically interpolated.
        """
        idx = [dr.gather(mi.UInt32, self._faces, prim_index * 3 + c) for c in range(3)]
        pos = self._object.vertex_positions.array
        P = [mi.Point3f(*(dr.gather(mi.Float, pos, i * 3 + k) for k in range(3))) for i in idx]
        w = _barycentric(p, *P)
        par = self.vertex_parameters.array
        return [sum(w[c] * dr.gather(mi.Float, par, idx[c] * 6 + k) for c in range(3))
                for k in range(6)]

    def _sionna_values(self, si):
        """Sionna's ``(eta_r, sigma, d, S)`` at each interaction of ``si``."""
        m = self.parameters_at(si.p, si.prim_index)
        omega = self.scene.angular_frequency if self.scene is not None else 2 * math.pi * 77e9
        k = self.scene.wavenumber if self.scene is not None else omega / 299_792_458.0
        cos_i = dr.abs(si.wi.z)
        eta = dr.exp(-dr.square(2.0 * k * m[2] * cos_i))
        return (dr.maximum(m[0], 1.0), dr.maximum(m[1], 0.0) * EPSILON_0 * omega,
                dr.maximum(m[5], 0.0), dr.safe_sqrt(1.0 - eta))

    def _evaluate(self, method, si, *args):
        saved = (self._eta_r, self._sigma, self._d, self._s)
        try:
            self._eta_r, self._sigma, self._d, self._s = self._sionna_values(si)
            return method(si, *args)
        finally:
            self._eta_r, self._sigma, self._d, self._s = saved

    def sample(self, ctx, si, sample1, sample2, active=True):
        """Sionna's ``sample`` with this interaction's parameters."""
        return self._evaluate(lambda s, *a: RadioMaterial.sample(self, ctx, s, *a), si,
                              sample1, sample2, active)

    def eval(self, ctx, si, wo, active=True):
        """Sionna's ``eval`` with this interaction's parameters."""
        return self._evaluate(lambda s, *a: RadioMaterial.eval(self, ctx, s, *a), si, wo, active)

    def pdf(self, ctx, si, wo, active=True):
        """Sionna's ``pdf`` with this interaction's parameters."""
        return self._evaluate(lambda s, *a: RadioMaterial.pdf(self, ctx, s, *a), si, wo, active)

    def to_string(self) -> str:
        n = self.vertex_parameters.shape[0]
        return f"VertexRadioMaterial(name={self.name!r}, label={self.label!r}, vertices={n})"


def _barycentric(p, p0, p1, p2):
    """Barycentric weights ``(w0, w1, w2)`` of ``p`` in triangle ``(p0, p1, p2)``."""
    v0, v1, v2 = p1 - p0, p2 - p0, p - p0
    d00, d01, d11 = dr.dot(v0, v0), dr.dot(v0, v1), dr.dot(v1, v1)
    d20, d21 = dr.dot(v2, v0), dr.dot(v2, v1)
    den = dr.maximum(d00 * d11 - d01 * d01, 1e-30)
    w1 = (d11 * d20 - d01 * d21) / den
    w2 = (d00 * d21 - d01 * d20) / den
    return 1.0 - w1 - w2, w1, w2
