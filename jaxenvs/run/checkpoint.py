"""Atomic, pickle-free checkpoints of a runner state pytree.

A checkpoint is ONE ``.npz`` file holding:

* ``leaf_00000`` ... : the flattened leaves of the state pytree as plain numpy arrays
  (PRNG key arrays are stored as their ``key_data`` and re-wrapped on load);
* ``__meta__``: a uint8 array of UTF-8 JSON with the format version, per-leaf dtype,
  shape and key implementation, the caller's metadata, and a SHA-256 checksum over every
  leaf's name, dtype, shape and bytes and over the rest of this record (so an edited
  record is caught as surely as an edited leaf).

Writing goes to a temporary file in the same directory, is flushed and fsynced, then
renamed over the target, so a crash or Ctrl-C never leaves a half-written checkpoint.
Reading uses ``allow_pickle=False``. Every way a file can fail to be a checkpoint of
this format (truncated, checksum mismatch, malformed or missing record fields, a foreign
format version, a state whose structure does not match the template) raises
:class:`CheckpointError` with a one-line message naming the file; no other exception
escapes :func:`read` and :func:`load` for a file that exists.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils

from jaxenvs import files

FORMAT = "jaxenvs-checkpoint"
FORMAT_VERSION = 2  # 2: the checksum covers the metadata record too
META_KEY = "__meta__"


class CheckpointError(ValueError):
    """A checkpoint file is missing, corrupt, truncated or does not fit the run."""


def _is_key(x: Any) -> bool:
    return isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _digest(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> str:
    """SHA-256 over every array (name, dtype, shape, bytes) and the record ``meta``
    without its ``sha256`` field (as canonical JSON)."""
    h = hashlib.sha256()
    record = {k: v for k, v in meta.items() if k != "sha256"}
    h.update(json.dumps(record, sort_keys=True, separators=(",", ":")).encode())
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        h.update(name.encode())
        h.update(str(arr.dtype).encode())
        h.update(repr(arr.shape).encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def save(path: str | Path, state: Any, metadata: dict[str, Any] | None = None) -> None:
    """Write ``state`` (any pytree of arrays) and JSON-able ``metadata`` atomically."""
    path = Path(path)
    leaves = jax.tree.leaves(state)
    arrays: dict[str, np.ndarray] = {}
    leaf_info = []
    for i, leaf in enumerate(leaves):
        impl = None
        if _is_key(leaf):
            impl = str(jax.random.key_impl(leaf))
            leaf = jax.random.key_data(leaf)
        if (
            isinstance(leaf, jax.Array)
            and not leaf.is_fully_addressable
            and not leaf.is_fully_replicated
        ):
            # split over several hosts: every process gathers the whole array
            leaf = multihost_utils.process_allgather(leaf, tiled=True)
        arr = np.asarray(jax.device_get(leaf))
        arrays[f"leaf_{i:05d}"] = arr
        leaf_info.append({"dtype": str(arr.dtype), "shape": list(arr.shape), "key_impl": impl})
    meta = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "num_leaves": len(leaves),
        "leaves": leaf_info,
        "metadata": metadata or {},
    }
    meta["sha256"] = _digest(arrays, meta)
    arrays[META_KEY] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]
    files.write_bytes(path, buf.getvalue(), fsync=True)


def _check_record(meta: Any, path: Path) -> None:
    """Raise :class:`CheckpointError` unless ``meta`` has every field :func:`load` uses,
    of the right type."""
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path}: corrupt checkpoint metadata (not a JSON object)")
    n, leaves = meta.get("num_leaves"), meta.get("leaves")
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        raise CheckpointError(f"{path}: corrupt checkpoint metadata (bad 'num_leaves': {n!r})")
    if not isinstance(leaves, list) or len(leaves) != n:
        raise CheckpointError(f"{path}: corrupt checkpoint metadata ('leaves' is not {n} records)")
    for i, info in enumerate(leaves):
        if not (
            isinstance(info, dict)
            and "key_impl" in info
            and isinstance(info["key_impl"], str | type(None))
            and isinstance(info.get("dtype"), str)
            and isinstance(info.get("shape"), list)
        ):
            raise CheckpointError(f"{path}: corrupt checkpoint metadata (leaf record {i})")
    if not isinstance(meta.get("metadata"), dict):
        raise CheckpointError(f"{path}: corrupt checkpoint metadata ('metadata' is not a mapping)")


def read(path: str | Path) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Verified raw contents: (leaf arrays in order, the stored metadata record)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except Exception as err:  # noqa: BLE001 - whatever np.load meets, the file is corrupt
        raise CheckpointError(
            f"{path}: not a readable checkpoint (truncated or corrupt: {type(err).__name__})"
        ) from None
    if META_KEY not in arrays:
        raise CheckpointError(f"{path}: not a jaxenvs checkpoint (no metadata)")
    try:
        meta = json.loads(arrays.pop(META_KEY).tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError, ValueError) as err:
        msg = f"{path}: corrupt checkpoint metadata ({type(err).__name__})"
        raise CheckpointError(msg) from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a jaxenvs checkpoint")
    if meta.get("version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint format version {meta.get('version')} is not supported "
            f"(this version reads {FORMAT_VERSION})"
        )
    if _digest(arrays, meta) != meta.get("sha256"):
        raise CheckpointError(f"{path}: checksum mismatch, the checkpoint is corrupt")
    _check_record(meta, path)
    n = meta["num_leaves"]
    names = [f"leaf_{i:05d}" for i in range(n)]
    if sorted(arrays) != names:
        raise CheckpointError(f"{path}: expected {n} arrays, found {len(arrays)}")
    return [arrays[name] for name in names], meta


def check_matches(path: str | Path, stored: Mapping[str, Any], expected: Mapping[str, Any]) -> None:
    """Raise :class:`CheckpointError` naming every key whose value in ``stored`` (a
    checkpoint's metadata) differs from ``expected`` (e.g. env id, algorithm, config).

    Nested mappings are compared key by key and named by dotted paths
    (``config.agent.alpha``); a key absent from ``stored`` counts as different.
    """
    diffs = _differences(stored, expected, "")
    if diffs:
        shown = "; ".join(diffs[:4]) + (f"; and {len(diffs) - 4} more" if len(diffs) > 4 else "")
        raise CheckpointError(f"{path}: the checkpoint is of another run: {shown}")


def _differences(stored: Any, expected: Any, prefix: str) -> list[str]:
    if isinstance(stored, Mapping) and isinstance(expected, Mapping):
        out = []
        for key in sorted(set(stored) | set(expected), key=str):
            name = f"{prefix}.{key}" if prefix else str(key)
            if key not in stored or key not in expected:
                where = "checkpoint" if key not in stored else "run"
                out.append(f"{name} is missing from the {where}")
            else:
                out.extend(_differences(stored[key], expected[key], name))
        return out
    if _jsonable(stored) != _jsonable(expected):
        return [f"{prefix} is {stored!r} in the checkpoint but {expected!r} in this run"]
    return []


def _jsonable(value: Any) -> Any:
    """``value`` as it reads back from JSON (tuples are lists)."""
    return json.loads(json.dumps(value, default=str))


def load(path: str | Path, template: Any) -> tuple[Any, dict[str, Any]]:
    """Restore a state shaped like ``template`` (a pytree or its ``eval_shape``).

    Returns ``(state, metadata)``; raises :class:`CheckpointError` when the file is
    unreadable or its leaves do not match the template's structure, shapes and dtypes.
    """
    leaves, meta = read(path)
    t_leaves, treedef = jax.tree.flatten(template)
    if len(t_leaves) != len(leaves):
        raise CheckpointError(
            f"{path}: the checkpoint holds {len(leaves)} arrays but this run's state has "
            f"{len(t_leaves)}; it was written by a different algorithm or config"
        )
    out = []
    for i, (arr, tmpl, info) in enumerate(zip(leaves, t_leaves, meta["leaves"], strict=True)):
        is_key = jax.dtypes.issubdtype(tmpl.dtype, jax.dtypes.prng_key)
        if is_key:
            if info["key_impl"] is None:
                raise CheckpointError(f"{path}: leaf {i} should be a PRNG key")
            try:
                leaf = jax.random.wrap_key_data(jax.numpy.asarray(arr), impl=info["key_impl"])
            except (TypeError, ValueError) as err:
                raise CheckpointError(f"{path}: leaf {i} is not a valid PRNG key ({err})") from None
        else:
            leaf = arr
        if tuple(leaf.shape) != tuple(tmpl.shape) or leaf.dtype != tmpl.dtype:
            raise CheckpointError(
                f"{path}: leaf {i} is {leaf.dtype}{list(leaf.shape)} but this run expects "
                f"{tmpl.dtype}{list(tmpl.shape)}; it was written by a different config"
            )
        out.append(jax.numpy.asarray(leaf) if not is_key else leaf)
    return jax.tree.unflatten(treedef, out), meta["metadata"]
