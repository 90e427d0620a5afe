"""CartPole-v0's PD controller as an exported policy, for the deploy tests (no training).

Logits ``(0, gains . obs)``: push right when ``0.1 x + 0.2 x' + theta + 0.3 theta' > 0``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxenvs.deploy.export import npz_bytes
from jaxenvs.deploy.runtime import FORMAT, FORMAT_VERSION, NumpyPolicy

PD_GAINS = np.array([0.1, 0.2, 1.0, 0.3], np.float32)


def pd_policy(path: Path, gains: np.ndarray = PD_GAINS) -> Path:
    """Write the PD controller with ``gains`` to ``path`` as an ``.npz`` policy; returns it."""
    kernel = np.stack([np.zeros(4, np.float32), gains], axis=1)
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "env_id": "CartPole-v0",
        "observation_size": "4",
        "action_size": "2",
        "discrete": "1",
        "control_dt": "0.02",
        "activation": "tanh",
    }
    policy = NumpyPolicy((kernel,), (np.zeros(2, np.float32),), None, True, meta)
    path.write_bytes(npz_bytes(policy))
    return path
