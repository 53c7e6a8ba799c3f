"""The quadrotor's physics, defined once (DESIGN 2, "One physics"; 6.1b).

Every physical formula of the model lives here with its equation in the docstring, and everything else calls
it: the physics model (:mod:`quad_modelling.core.models.physics`), its identification regressors
(:mod:`quad_modelling.core.identification.physics_fit`), the hybrid's torch twin
(:mod:`quad_modelling.core.training.physics_torch`: the same functions fed tensors), the simulator's mixer
(:mod:`quad_modelling.core.sim.control`), the prediction bounds (:mod:`quad_modelling.core.models.bounds`) and the
thesis greybox's derived constants (:mod:`quad_modelling.core.models.greybox`).

* :mod:`~quad_modelling.core.physics.parameters`: the constants (PhysicsParameters) read from a vehicle file;
* :mod:`~quad_modelling.core.physics.rotors`: command map, delay, rotor lag, thrust, yaw torque, hover speed,
  battery scaling;
* :mod:`~quad_modelling.core.physics.aero`: rotor drag force and moment, ground-effect factor;
* :mod:`~quad_modelling.core.physics.rigid_body`: wrench, gyroscopic torque, Newton-Euler derivative,
  integration step, mixer allocation;
* :mod:`~quad_modelling.core.physics.symmetry`: the airframe's turns and mirror images, a flight's image under one;
* :mod:`~quad_modelling.core.physics.arrays`: the few array operations, numpy or torch.

The truth simulator (:mod:`quad_modelling.core.sim`) keeps its own, deliberately richer effect forms
(``docs/simulator.md`` lists them next to these).
"""
