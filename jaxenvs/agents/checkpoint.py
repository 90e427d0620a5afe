"""Atomic, pickle-free checkpoints of a runner state pytree.

A checkpoint is ONE ``.npz`` file holding:

* ``leaf_00000`` ... : the flattened leaves of the state pytree as plain numpy arrays
  (PRNG key arrays are stored as their ``key_data`` and re-wrapped on load);
* ``__meta__``: a uint8 array of UTF-8 JSON with the format version, per-leaf dtype,
  shape and key implementation, the caller's metadata, and a SHA-256 checksum over every
  leaf's name, dtype, shape and bytes.

Writing goes to a temporary file in the same directory, is flushed and fsynced, then
renamed over the target, so a crash or Ctrl-C never leaves a half-written checkpoint.
Reading uses ``allow_pickle=False``; a truncated file, a checksum mismatch, a foreign
format version or a state whose structure does not match the template raises
:class:`CheckpointError` naming the file.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxenvs import files

FORMAT = "jaxenvs-checkpoint"
FORMAT_VERSION = 1
META_KEY = "__meta__"


class CheckpointError(ValueError):
    """A checkpoint file is missing, corrupt, truncated or does not fit the run."""


def _is_key(x: Any) -> bool:
    return isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
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
        arr = np.asarray(jax.device_get(leaf))
        arrays[f"leaf_{i:05d}"] = arr
        leaf_info.append({"dtype": str(arr.dtype), "shape": list(arr.shape), "key_impl": impl})
    meta = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "num_leaves": len(leaves),
        "leaves": leaf_info,
        "metadata": metadata or {},
        "sha256": _digest(arrays),
    }
    arrays[META_KEY] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]
    files.write_bytes(path, buf.getvalue(), fsync=True)


def read(path: str | Path) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Verified raw contents: (leaf arrays in order, the stored metadata record)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as err:
        raise CheckpointError(
            f"{path}: not a readable checkpoint (truncated or corrupt: {err})"
        ) from None
    if META_KEY not in arrays:
        raise CheckpointError(f"{path}: not a jaxenvs checkpoint (no metadata)")
    try:
        meta = json.loads(arrays.pop(META_KEY).tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise CheckpointError(f"{path}: corrupt checkpoint metadata ({err})") from None
    if meta.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a jaxenvs checkpoint")
    if meta.get("version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint format version {meta.get('version')} is not supported "
            f"(this version reads {FORMAT_VERSION})"
        )
    if _digest(arrays) != meta.get("sha256"):
        raise CheckpointError(f"{path}: checksum mismatch, the checkpoint is corrupt")
    n = meta["num_leaves"]
    if len(arrays) != n:
        raise CheckpointError(f"{path}: expected {n} arrays, found {len(arrays)}")
    return [arrays[f"leaf_{i:05d}"] for i in range(n)], meta


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
            leaf = jax.random.wrap_key_data(jax.numpy.asarray(arr), impl=info["key_impl"])
        else:
            leaf = arr
        if tuple(leaf.shape) != tuple(tmpl.shape) or leaf.dtype != tmpl.dtype:
            raise CheckpointError(
                f"{path}: leaf {i} is {leaf.dtype}{list(leaf.shape)} but this run expects "
                f"{tmpl.dtype}{list(tmpl.shape)}; it was written by a different config"
            )
        out.append(jax.numpy.asarray(leaf) if not is_key else leaf)
    return jax.tree.unflatten(treedef, out), meta["metadata"]
