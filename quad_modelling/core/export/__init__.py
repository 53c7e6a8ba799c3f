"""Exports of the identified models for use outside this package (``quad-modelling export``, docs/export.md).

* :mod:`~quad_modelling.core.export.casadi_model`: the physics model with its switched-on terms (and a hybrid's
  residual net) as CasADi Functions f(x, u) and F(x, u, dt), built from the one physics definition
  (:mod:`quad_modelling.core.physics`) through its symbolic array backend.
"""
