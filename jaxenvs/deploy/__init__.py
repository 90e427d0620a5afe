"""From simulation to a robot: export a trained policy and run it without JAX.

* :mod:`jaxenvs.deploy.export`: ``jaxenvs export``, a PPO run's greedy policy as ONNX or
  as a ``.npz`` of numpy arrays, with the observation normaliser and the greedy head inside;
* :mod:`jaxenvs.deploy.runtime`: the numpy-only runtime of the ``.npz`` (one file to copy);
* :mod:`jaxenvs.deploy.parity`: the check that an exported policy acts as the JAX one.

This package imports nothing heavy at import time.
"""
