"""Radio materials: ITU-R P.2040 data and closed-form interface physics.

``itu_table``  ITU-R P.2040-3 Table 3 fits, per-material initial values of the
               six per-vertex parameters of the mmIR BSDF.
``fresnel``    complex Fresnel and single-layer slab coefficients (ITU-R
               P.2040-3 eqs. (37), (43), (44)) and the energy gate
               ``A = f_s |R_s|^2 + f_p |R_p|^2``, in NumPy and Dr.Jit.

Only NumPy is imported here; Dr.Jit is imported on first use of a Dr.Jit code
path, after :func:`sionna_mmir.utils.backend.init_backend`.
"""
from .fresnel import (
    COS_THETA_MIN,
    SPEED_OF_LIGHT,
    InterfaceCoefficients,
    SlabCoefficients,
    complex_permittivity,
    energy_gate,
    fresnel_coefficients,
    slab_coefficients,
)
from .itu_table import (
    EPSILON_0,
    ITU_P2040_TABLE3,
    ITU_TABLE,
    SURFACE_DEFAULTS,
    VERTEX_PARAMETER_NAMES,
    ItuMaterial,
    ItuRow,
    SurfaceDefaults,
    available_materials,
    default_vertex_parameters,
    eps_imag_from_conductivity,
    itu_material,
)

__all__ = [
    "COS_THETA_MIN",
    "EPSILON_0",
    "ITU_P2040_TABLE3",
    "ITU_TABLE",
    "InterfaceCoefficients",
    "ItuMaterial",
    "ItuRow",
    "SPEED_OF_LIGHT",
    "SURFACE_DEFAULTS",
    "SlabCoefficients",
    "SurfaceDefaults",
    "VERTEX_PARAMETER_NAMES",
    "available_materials",
    "complex_permittivity",
    "default_vertex_parameters",
    "energy_gate",
    "eps_imag_from_conductivity",
    "fresnel_coefficients",
    "itu_material",
    "slab_coefficients",
]
