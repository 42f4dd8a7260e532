"""The policy's TensorDict modules: the controllers (linear, MLP), SDE's maths, parameters, noise and
distribution, and PGPE's parameter exploration."""
