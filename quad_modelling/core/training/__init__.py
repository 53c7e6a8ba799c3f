"""Learning models from flights: the NARX and hybrid trainings (torch), the shared rollout (multi-step) trainer,
the torch twin of the physics step the hybrid trains through, and the direct model's ridge fits (numpy).

Predicting never needs this package (or torch): the trained weights are numpy arrays in the model files that
:mod:`quad_modelling.core.models` loads. The physics model's constants are identified, not trained:
:mod:`quad_modelling.core.identification.physics_fit`.
"""
