"""mmWave BSDF lobes in the local shading frame (normal ``+z``).

Mitsuba-style modules, one per lobe, each with ``eval(wi, wo, params)``,
``pdf(wi, wo, params)`` and ``sample(wi, u2, params) -> (wo, pdf)`` written in
Dr.Jit (differentiable w.r.t. the lobe parameter):

* :mod:`.lambertian`  ``f_broad``
* :mod:`.vmf`         ``f_SPM`` / ``f_dir`` (von Mises-Fisher, Wood 1994)
* :mod:`.ggx`         ``f_KA`` (GGX, Walter et al. 2007; VNDF, Heitz 2018)
* :mod:`.mmwave`      the combined mmIR BSDF (paper Sec. 3.2)

``eval`` returns the BSDF value without the cosine ``cos(theta_o)``.
"""
from . import ggx, lambertian, mmwave, vmf
from .mmwave import MMWaveParams

__all__ = ["ggx", "lambertian", "mmwave", "vmf", "MMWaveParams"]
