"""The plant: quaternions, the rigid body, reaction wheels and their motors, other actuators, disturbances,
the linearised model, and the compiled kernels they step with. Imports only the core root (paramspec, ...)."""
