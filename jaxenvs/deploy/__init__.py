"""From simulation to a robot: export a trained policy and run it without JAX.

* :mod:`jaxenvs.deploy.export`: ``jaxenvs export``, a PPO run's greedy policy as ONNX or
  as a ``.npz`` of numpy arrays, with the observation normaliser and the greedy head inside;
* :mod:`jaxenvs.deploy.runtime`: the numpy-only runtime of the ``.npz`` (one file to copy);
* :mod:`jaxenvs.deploy.parity`: the check that an exported policy acts as the JAX one;
* :mod:`jaxenvs.deploy.wire`: the robot link's messages and their framing on TCP;
* :mod:`jaxenvs.deploy.simrobot`: ``jaxenvs robot``, a task's robot simulated in MuJoCo C
  in real time behind that link;
* :mod:`jaxenvs.deploy.link`: the deploy loop's side of the link (a
  :class:`~jaxenvs.robots.interface.RobotLink` over TCP);
* :mod:`jaxenvs.deploy.loop`: ``jaxenvs deploy``, the real-time loop, its safety stops and
  its summary;
* :mod:`jaxenvs.deploy.log`: the loop's MCAP log, and reading it back for ``jaxenvs render
  --log``.

This package imports nothing heavy at import time.
"""
