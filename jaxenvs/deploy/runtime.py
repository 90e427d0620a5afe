"""Run an exported jaxenvs policy with numpy alone: ``NumpyPolicy.load(path)(obs) -> action``.

This file imports numpy and the standard library only, so it can be copied on its own to
a robot's computer. It reads the ``.npz`` that ``jaxenvs export RUN --format npz`` writes
(see :mod:`jaxenvs.deploy.export`) and computes exactly what ``jaxenvs eval`` acts with:

1. observation normalisation, when the run used it:
   ``clip((obs - obs_mean) / obs_std, -obs_clip, obs_clip)``;
2. the actor MLP: ``x @ kernel_i + bias_i``, ``tanh`` after every layer but the last;
3. the greedy action: ``argmax`` of the logits (int64) for a discrete task, else the mean
   clipped to the action space ``[-1, 1]`` (float32).

A file's arrays: ``kernel_0, bias_0, ..., kernel_{L-1}, bias_{L-1}``; ``obs_mean``,
``obs_std`` and ``obs_clip`` when it normalises; ``metadata``, a JSON object of strings
(the same keys and values as the ONNX file's ``metadata_props``: ``env_id``,
``observation_size``, ``action_size``, ``discrete``, ``control_dt``, the spaces, the
jaxenvs version, ...).

    from runtime import NumpyPolicy
    policy = NumpyPolicy.load("policy.npz")
    action = policy(obs)          # obs: (obs_size,) or (N, obs_size)
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: the ``format`` entry of an exported policy's metadata, and the version this file reads
FORMAT = "jaxenvs-policy"
FORMAT_VERSION = "1"
#: the hidden layers' activation this runtime implements
ACTIVATIONS = {"tanh": np.tanh}


class PolicyFileError(ValueError):
    """A file that is not an exported policy this runtime can run; the message names it."""


@dataclass(frozen=True)
class Normalizer:
    """``clip((obs - mean) / std, -clip, clip)``, float32."""

    mean: np.ndarray
    std: np.ndarray
    clip: np.float32

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.clip((obs - self.mean) / self.std, -self.clip, self.clip)


@dataclass(frozen=True)
class NumpyPolicy:
    """The greedy policy of an exported run, as float32 numpy arrays.

    Attributes:
      kernels, biases: the actor MLP's layers, ``kernels[i]`` of shape ``(in, out)``.
      normalizer: the observation normaliser (``None``: not normalised).
      discrete: argmax of the logits (else the mean clipped to ``[-1, 1]``).
      metadata: the file's metadata (strings; see the module docstring).
    """

    kernels: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    normalizer: Normalizer | None
    discrete: bool
    metadata: dict[str, str]

    @property
    def observation_size(self) -> int:
        return int(self.kernels[0].shape[0])

    @property
    def action_size(self) -> int:
        """The number of actuators, or of discrete actions."""
        return int(self.kernels[-1].shape[1])

    @property
    def control_dt(self) -> float:
        """Seconds between two actions, as the policy was trained."""
        return float(self.metadata["control_dt"])

    @classmethod
    def load(cls, path: str | Path) -> NumpyPolicy:
        """Read and check an exported ``.npz``; :class:`PolicyFileError` when it is not one."""
        path = Path(path)
        if not path.is_file():
            raise PolicyFileError(f"no policy file at {path}")
        try:
            with np.load(path, allow_pickle=False) as npz:
                arrays = {name: npz[name] for name in npz.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
            raise PolicyFileError(f"{path}: not a readable npz ({type(err).__name__})") from None
        metadata = _metadata(arrays.pop("metadata", None), path)
        return _from_arrays(arrays, metadata, path)

    def logits(self, obs: Any) -> np.ndarray:
        """The actor's last layer for ``obs`` of shape ``(N, obs_size)``: logits for a
        discrete task, the Gaussian mean before clipping for a continuous one."""
        x = np.asarray(obs, np.float32)
        if self.normalizer is not None:
            x = self.normalizer(x)
        last = len(self.kernels) - 1
        for i, (kernel, bias) in enumerate(zip(self.kernels, self.biases, strict=True)):
            x = x @ kernel + bias
            if i < last:
                x = np.tanh(x)
        return x

    def __call__(self, obs: Any) -> np.ndarray:
        """The greedy action(s): ``(action_size,)`` float32 or an int64 scalar for one
        observation ``(obs_size,)``; a leading batch axis for ``(N, obs_size)``."""
        x = np.asarray(obs, np.float32)
        if x.ndim not in (1, 2) or x.shape[-1] != self.observation_size:
            raise ValueError(
                f"expected observations of shape ({self.observation_size},) or "
                f"(N, {self.observation_size}), got {x.shape}"
            )
        out = self.logits(x[None] if x.ndim == 1 else x)
        if self.discrete:
            action = np.argmax(out, axis=-1).astype(np.int64)
        else:
            action = np.clip(out, np.float32(-1.0), np.float32(1.0))
        return action[0] if x.ndim == 1 else action


def _metadata(raw: np.ndarray | None, path: Path) -> dict[str, str]:
    if raw is None or raw.dtype.kind != "U" or raw.ndim != 0:
        raise PolicyFileError(f"{path}: not an exported jaxenvs policy (no metadata)")
    try:
        meta = json.loads(str(raw))
    except json.JSONDecodeError:
        raise PolicyFileError(f"{path}: corrupt policy metadata (not JSON)") from None
    if not isinstance(meta, dict) or not all(isinstance(v, str) for v in meta.values()):
        raise PolicyFileError(f"{path}: corrupt policy metadata (not a mapping of strings)")
    if meta.get("format") != FORMAT:
        raise PolicyFileError(f"{path}: not an exported jaxenvs policy")
    if meta.get("format_version") != FORMAT_VERSION:
        raise PolicyFileError(
            f"{path}: policy format version {meta.get('format_version')} is not supported "
            f"(this runtime reads {FORMAT_VERSION})"
        )
    if meta.get("activation") not in ACTIVATIONS or meta.get("discrete") not in ("0", "1"):
        raise PolicyFileError(f"{path}: corrupt policy metadata (activation or discrete)")
    return meta


def _from_arrays(arrays: dict[str, np.ndarray], meta: dict[str, str], path: Path) -> NumpyPolicy:
    """The policy of a file's arrays, every shape and dtype checked against the others."""
    layers = 0
    while f"kernel_{layers}" in arrays:
        layers += 1
    norm = ("obs_mean", "obs_std", "obs_clip")
    expected = {f"{k}_{i}" for i in range(layers) for k in ("kernel", "bias")}
    if "obs_mean" in arrays:
        expected |= set(norm)
    if layers == 0 or set(arrays) != expected:
        raise PolicyFileError(f"{path}: corrupt policy (arrays {sorted(arrays)})")
    if any(a.dtype != np.float32 for a in arrays.values()):
        raise PolicyFileError(f"{path}: corrupt policy (arrays must be float32)")
    kernels = tuple(arrays[f"kernel_{i}"] for i in range(layers))
    biases = tuple(arrays[f"bias_{i}"] for i in range(layers))
    width = kernels[0].shape[0] if kernels[0].ndim == 2 else -1
    for i, (k, b) in enumerate(zip(kernels, biases, strict=True)):
        if k.ndim != 2 or k.shape[0] != width or b.shape != (k.shape[1],):
            raise PolicyFileError(f"{path}: corrupt policy (layer {i} does not fit the one before)")
        width = k.shape[1]
    obs_size = kernels[0].shape[0]
    if meta.get("observation_size") != str(obs_size) or meta.get("action_size") != str(width):
        raise PolicyFileError(f"{path}: corrupt policy (sizes differ from its metadata)")
    normalizer = None
    if "obs_mean" in arrays:
        mean, std = arrays["obs_mean"], arrays["obs_std"]
        clip = np.float32(arrays["obs_clip"])
        if mean.shape != (obs_size,) or std.shape != (obs_size,) or arrays["obs_clip"].ndim:
            raise PolicyFileError(f"{path}: corrupt policy (normaliser shapes)")
        if not (np.all(std > 0) and clip > 0):
            raise PolicyFileError(f"{path}: corrupt policy (normaliser values)")
        normalizer = Normalizer(mean, std, clip)
    return NumpyPolicy(kernels, biases, normalizer, meta["discrete"] == "1", meta)


__all__ = ["FORMAT", "FORMAT_VERSION", "Normalizer", "NumpyPolicy", "PolicyFileError"]
