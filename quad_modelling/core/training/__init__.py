"""Learning models from flights (torch): the NARX and hybrid trainings, the shared rollout (multi-step) trainer,
and the torch twin of the physics step the hybrid trains through.

Predicting never needs this package (or torch): the trained weights are numpy arrays in the model files that
:mod:`quad_modelling.core.models` loads. The physics model's constants are identified, not trained:
:mod:`quad_modelling.core.identification.physics_fit`.
"""
