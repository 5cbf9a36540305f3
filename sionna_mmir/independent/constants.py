"""Physical constants of the independent reference renderer (SI, CODATA 2018)."""

#: Speed of light in vacuum [m/s].
C0 = 299_792_458.0
#: Vacuum permittivity [F/m].
EPS0 = 8.8541878128e-12
