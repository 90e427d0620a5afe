"""``jaxenvs export``: the greedy policy of a PPO run as ONNX or as a numpy-only ``.npz``.

The exported function is ``action = policy(obs)`` exactly as ``jaxenvs eval`` acts
(:func:`jaxenvs.agents.ppo.make_trainer`'s ``act``), of the seed ``eval``/``view`` use (the
best final evaluation, unless ``seed`` picks another):

* the observation normaliser, when the run used one: ``clip((obs - mean) / std, -c, c)``
  with the running mean and ``std = sqrt(var + 1e-8)`` of the checkpoint;
* the actor MLP (tanh hidden layers);
* the greedy head: ``argmax`` of the logits (int64) for a discrete task, the Gaussian mean
  clipped to ``[-1, 1]`` (float32) for a continuous one.

:func:`policy_of_run` reads it into a :class:`~jaxenvs.deploy.runtime.NumpyPolicy`;
:func:`onnx_model` and :func:`npz_bytes` turn that into the two formats, which carry the
same metadata (:func:`run_metadata`); :func:`export` writes one atomically.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from jaxenvs import files
from jaxenvs.deploy.runtime import FORMAT, FORMAT_VERSION, Normalizer, NumpyPolicy

FORMATS = ("onnx", "npz")
#: the ONNX operator set and IR version of exported models (onnxruntime >= 1.14 runs them)
OPSET, IR_VERSION = 17, 8
#: the file ``export`` writes in the run directory when no ``out`` is given
DEFAULT_NAME = "exported_policy"
ACTIVATION = "tanh"  # jaxenvs.agents.networks.MLP's hidden activation


class ExportError(ValueError):
    """A run that cannot be exported, or an output that cannot be written."""


# ------------------------------------------------------------------------- the policy
def _best_seed(run_dir: Path, num_seeds: int) -> int:
    """The seed ``jaxenvs view``/``render --policy`` act with: the best final evaluation
    (seed 0 when the run has no summary)."""
    from jaxenvs.run.run_config import SUMMARY_FILE

    try:
        per_seed = json.loads((run_dir / SUMMARY_FILE).read_text())["eval_mean_return_per_seed"]
        return int(np.argmax(per_seed)) if len(per_seed) == num_seeds else 0
    except (OSError, ValueError, KeyError, TypeError):
        return 0


def _bound(x: float) -> float | str:
    return float(x) if math.isfinite(x) else ("inf" if x > 0 else "-inf")


def space_json(space: Any) -> str:
    """A gymnasium ``Box`` or ``Discrete`` as strict JSON: ``{"type": "Discrete", "n": 2}``
    or ``{"type": "Box", "shape": [4], "dtype": "float32", "low": [...], "high": [...]}``
    (an infinite bound is the string ``"inf"`` or ``"-inf"``)."""
    import gymnasium

    if isinstance(space, gymnasium.spaces.Discrete):
        return json.dumps({"type": "Discrete", "n": int(space.n)})
    if isinstance(space, gymnasium.spaces.Box):
        return json.dumps(
            {
                "type": "Box",
                "shape": list(space.shape),
                "dtype": str(space.dtype),
                "low": [_bound(v) for v in np.ravel(space.low)],
                "high": [_bound(v) for v in np.ravel(space.high)],
            }
        )
    raise ExportError(f"cannot describe a {type(space).__name__} space")


def run_metadata(resolved: Any, env: Any, seed: int, normalize: bool) -> dict[str, str]:
    """The metadata both formats carry (strings, as ONNX's ``metadata_props``)."""
    import jaxenvs

    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "jaxenvs_version": jaxenvs.__version__,
        "env_id": resolved.env_id,
        "algo": resolved.algo,
        "seed": str(seed),
        "physics": str(env.physics),
        "observation_size": str(env.observation_size),
        "action_size": str(env.action_size),
        "discrete": "1" if env.discrete else "0",
        "observation_space": space_json(env.observation_space),
        "action_space": space_json(env.action_space),
        "control_dt": repr(float(env.control_dt)),
        "activation": ACTIVATION,
        "normalize_obs": "1" if normalize else "0",
        "env_config": json.dumps(deploy_config(resolved.env, env), sort_keys=True),
    }


def deploy_config(config: Any, env: Any) -> dict[str, Any]:
    """What ``jaxenvs deploy`` reads of the trained env: :func:`env_config_changes`, and
    every one of the task's ``deploy_fields`` whatever its value (so a later change of a
    default cannot change what an exported policy is deployed with)."""
    out = env_config_changes(config)
    for name in getattr(env, "deploy_fields", ()):
        value = getattr(config, name)
        out[name] = list(value) if isinstance(value, tuple) else value
    return out


def env_config_changes(config: Any) -> dict[str, Any]:
    """The fields of a task config that differ from its class's defaults (JSON types),
    e.g. ``{"action_delay_max": 2}``: what ``jaxenvs deploy`` needs of the trained env."""
    default = type(config)()
    out = {}
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if value != getattr(default, field.name):
            out[field.name] = list(value) if isinstance(value, tuple) else value
    return out


def _actor_layers(params: Any, hidden: tuple[int, ...], where: Path) -> list[tuple[Any, Any]]:
    """``(kernel, bias)`` of each layer of the actor MLP of PPO's network params."""
    try:
        actor = params["params"]["actor"]
        names = [f"Dense_{i}" for i in range(len(hidden) + 1)]
        if sorted(actor) != sorted(names):
            raise KeyError(sorted(actor))
        return [(actor[n]["kernel"], actor[n]["bias"]) for n in names]
    except (KeyError, TypeError) as err:
        raise ExportError(
            f"{where}: the actor network is not a {len(hidden)}-layer MLP ({err})"
        ) from None


def check_seed(run_dir: str | Path, seed: int | None) -> None:
    """:class:`ExportError` naming the run's range when ``seed`` is not one of its seeds
    (read from its config: nothing is restored)."""
    from jaxenvs.run.run_config import load_run_config

    if seed is None:
        return
    num_seeds = int(load_run_config(run_dir).train.num_seeds)
    if not 0 <= seed < num_seeds:
        raise ExportError(f"--seed must be between 0 and {num_seeds - 1} for {run_dir}")


def policy_of_run(run_dir: str | Path, seed: int | None = None) -> NumpyPolicy:
    """The greedy policy of seed ``seed`` (default: the best) of a PPO run directory."""
    import jax

    from jaxenvs.run import restore
    from jaxenvs.run.run_config import load_run_config

    run_dir = Path(run_dir)
    algo = load_run_config(run_dir).algo
    if algo != "ppo":
        raise ExportError(f"{run_dir} is a {algo} run; export needs a PPO run")
    resolved, env, trainer, params = restore.restore_policy(run_dir)
    num_seeds = jax.tree.leaves(params)[0].shape[0]
    if seed is None:
        seed = _best_seed(run_dir, num_seeds) if num_seeds > 1 else 0
    elif not 0 <= seed < num_seeds:
        raise ExportError(f"--seed must be between 0 and {num_seeds - 1} for {run_dir}")
    pp = jax.device_get(jax.tree.map(lambda x: x[seed], params))
    cfg = resolved.agent
    layers = _actor_layers(pp.params, tuple(cfg.actor_hidden), run_dir)
    f32 = np.float32
    normalizer = None
    if cfg.normalize_obs:
        mean = np.asarray(pp.obs_stats.mean, f32)
        std = np.sqrt(np.asarray(pp.obs_stats.var, f32) + f32(1e-8))  # as ppo.normalize
        normalizer = Normalizer(mean, std, f32(cfg.obs_clip))
    return NumpyPolicy(
        kernels=tuple(np.asarray(k, f32) for k, _ in layers),
        biases=tuple(np.asarray(b, f32) for _, b in layers),
        normalizer=normalizer,
        discrete=bool(env.discrete),
        metadata=run_metadata(resolved, env, seed, cfg.normalize_obs),
    )


# ------------------------------------------------------------------------ the formats
def npz_bytes(policy: NumpyPolicy) -> bytes:
    """The ``.npz`` :meth:`NumpyPolicy.load` reads (layout: :mod:`jaxenvs.deploy.runtime`)."""
    arrays: dict[str, np.ndarray] = {}
    for i, (k, b) in enumerate(zip(policy.kernels, policy.biases, strict=True)):
        arrays[f"kernel_{i}"], arrays[f"bias_{i}"] = k, b
    norm = policy.normalizer
    if norm is not None:
        arrays["obs_mean"], arrays["obs_std"] = norm.mean, norm.std
        arrays["obs_clip"] = np.asarray(norm.clip, np.float32)
    arrays["metadata"] = np.array(json.dumps(policy.metadata, sort_keys=True))
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]
    return buf.getvalue()


def onnx_model(policy: NumpyPolicy) -> Any:
    """The policy as a checked ``onnx.ModelProto``: input ``obs`` float32 ``[N, obs_size]``,
    output ``action`` (float32 ``[N, action_size]``, or int64 ``[N]`` for a discrete task),
    the metadata in ``metadata_props``. Needs the ``onnx`` package."""
    try:
        import onnx
        from onnx import TensorProto, helper, numpy_helper
    except ImportError:
        raise ExportError(
            "the onnx format needs the onnx package: pip install 'jaxenvs[export]'"
        ) from None

    f32 = np.float32
    inits = []
    nodes = []

    def const(name: str, value: Any) -> str:
        inits.append(numpy_helper.from_array(np.asarray(value, f32), name))
        return name

    x = "obs"
    norm = policy.normalizer
    if norm is not None:
        nodes += [
            helper.make_node("Sub", [x, const("obs_mean", norm.mean)], ["obs_centred"]),
            helper.make_node("Div", ["obs_centred", const("obs_std", norm.std)], ["obs_z"]),
            helper.make_node(
                "Clip",
                [
                    "obs_z",
                    const("obs_clip_low", -norm.clip),
                    const("obs_clip_high", norm.clip),
                ],
                ["obs_normalised"],
            ),
        ]
        x = "obs_normalised"
    last = len(policy.kernels) - 1
    for i, (k, b) in enumerate(zip(policy.kernels, policy.biases, strict=True)):
        out = f"dense_{i}"
        nodes.append(
            helper.make_node("Gemm", [x, const(f"kernel_{i}", k), const(f"bias_{i}", b)], [out])
        )
        if i < last:
            nodes.append(helper.make_node("Tanh", [out], [f"hidden_{i}"]))
            out = f"hidden_{i}"
        x = out
    if policy.discrete:
        nodes.append(helper.make_node("ArgMax", [x], ["action"], axis=1, keepdims=0))
        action = helper.make_tensor_value_info("action", TensorProto.INT64, ["N"])
    else:
        low, high = const("action_low", -1.0), const("action_high", 1.0)
        nodes.append(helper.make_node("Clip", [x, low, high], ["action"]))
        action = helper.make_tensor_value_info(
            "action", TensorProto.FLOAT, ["N", policy.action_size]
        )
    obs = helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["N", policy.observation_size])
    graph = helper.make_graph(nodes, "jaxenvs_policy", [obs], [action], inits)
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="jaxenvs",
        producer_version=policy.metadata["jaxenvs_version"],
        doc_string=f"greedy PPO policy of {policy.metadata['env_id']}: action = policy(obs)",
    )
    model.ir_version = IR_VERSION
    helper.set_model_props(model, dict(policy.metadata))
    onnx.checker.check_model(model, full_check=True)
    return model


# ---------------------------------------------------------------------------- writing
def output_path(run_dir: str | Path, fmt: str, out: str | Path | None) -> Path:
    """Where ``export`` writes: ``out``, or ``RUN/exported_policy.<fmt>``; raises
    :class:`ExportError` for an unknown format, an ``out`` named as the other format
    (``--format npz --out m.onnx``) or a place that cannot be written."""
    if fmt not in FORMATS:
        raise ExportError(f"unknown format {fmt!r}; choose from {', '.join(FORMATS)}")
    path = Path(out) if out is not None else Path(run_dir) / f"{DEFAULT_NAME}.{fmt}"
    suffix = path.suffix.lower().lstrip(".")
    if suffix in FORMATS and suffix != fmt:
        raise ExportError(f"--out {path} is named as {suffix}, but --format is {fmt}")
    if path.is_dir():
        raise ExportError(f"cannot write {path}: it is a directory")
    if not path.parent.is_dir():
        raise ExportError(f"cannot write {path}: directory {path.parent} does not exist")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise ExportError(f"cannot write {path}: directory {path.parent} is not writable")
    return path


def export(
    run_dir: str | Path, fmt: str, out: str | Path | None = None, seed: int | None = None
) -> tuple[Path, NumpyPolicy]:
    """Write the greedy policy of a PPO run as ``fmt`` (``onnx`` or ``npz``) to ``out``
    (default ``RUN/exported_policy.<fmt>``), atomically; returns the path and the policy."""
    path = output_path(run_dir, fmt, out)
    policy = policy_of_run(run_dir, seed)
    data = onnx_model(policy).SerializeToString() if fmt == "onnx" else npz_bytes(policy)
    try:
        files.write_bytes(path, data, fsync=True)
    except OSError as err:
        raise ExportError(f"cannot write {path}: {err.strerror or err}") from None
    return path, policy


__all__ = [
    "DEFAULT_NAME",
    "FORMATS",
    "ExportError",
    "check_seed",
    "export",
    "npz_bytes",
    "onnx_model",
    "output_path",
    "policy_of_run",
    "run_metadata",
    "space_json",
]
