"""Transport stages of the radar path solver, one concern per module.

==================  ==========================================================
``state``           per-call constants (:class:`SolverContext`), the per-lane
                    path state (:class:`PathState`) and the local quantities at
                    the current interaction (:class:`Surface`)
``surface``         geometry, deferred BSDF weight and materials at ``x_l``
``connection``      the deterministic connection ``x_l -> Tx`` (visibility)
``coherent``        the physical-optics (Kirchhoff) field of specular chains
``aperture``        the lit footprints of the facet quadrature's chains
``clip_lines``      where a triangle's lit region ends (mesh topology)
``scattered``       the BSDF-scattered speckle field and its reciprocal twin
``continuation``    mirror / BSDF choice, Russian roulette, the next segment
``diffraction``     free-space diffraction (FSD) as a continuation event
``motion``          delay rates from object and radar velocities (Doppler)
==================  ==========================================================

:class:`~sionna_mmir.paths.solver.RadarPathSolver` calls them in that order
at every depth; each stage reads the state and the surface and returns or
updates what it owns.
"""
