"""Traced programs kept on disk (``jax.export``), beside the compile cache.

JAX's persistent compilation cache (:mod:`jaxenvs.run.compile_cache`) lets a second run skip
XLA's compile, but not tracing: the Python that builds the program (the MJX step inside
``vmap`` and ``scan``, the PPO update, the evaluator) runs again in every process, and on
a small CPU that is most of a warm start (about 7 s of CartPole-v0's PPO run, measured in
``benchmarks/RESULTS.md``). This module serialises the traced program itself with
``jax.export`` the first time and, on later runs, loads it instead of tracing; its
compile then hits the persistent cache as before.

A stored program is looked up by a key that covers everything the trace depends on: a
caller-chosen name and config, the argument shapes, dtypes and tree structure, the
versions of jax, jaxlib, mujoco, flax and optax, the backend and device kind, the x64
flag, and a digest of every source and model file of the jaxenvs package. Anything else a
program closes over must be in the caller's config (the runner only uses this for tasks
defined in the package). The file holds the serialised module and a JSON description
of the output's structure (no pickle): custom pytree nodes in the output are described by
reference to example structures the caller passes in (``known``).

Trust: every file carries its own key and a SHA-256 digest of its content, and is written
atomically. A file that is truncated, altered, stored under another key's name, or whose
module fails to deserialise or compile is discarded with one warning and the program is
traced and stored again: a damaged store costs a trace, never a failed run or a wrong
program.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import importlib.metadata
import json
import struct
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax

from jaxenvs import files
from jaxenvs.core.xla import jit

#: subdirectory of the compile-cache directory that holds exported programs.
SUBDIR = "programs"
#: the ``jaxenvs`` package (this file is ``jaxenvs/run/program_cache.py``)
_PACKAGE = Path(__file__).resolve().parents[1]
_SOURCE_SUFFIXES = (".py", ".xml", ".yaml", ".cc")
_VERSIONED = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax")


def source_files() -> list[Path]:
    """The package's source, model and config files, every subpackage's, sorted."""
    return [
        path
        for path in sorted(_PACKAGE.rglob("*"))
        if path.suffix in _SOURCE_SUFFIXES and "__pycache__" not in path.parts
    ]


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-256 over :func:`source_files` (paths relative to the package, and contents)."""
    h = hashlib.sha256()
    for path in source_files():
        h.update(str(path.relative_to(_PACKAGE)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def _environment() -> dict[str, Any]:
    versions: dict[str, str | None] = {}
    for name in _VERSIONED:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    device = jax.devices()[0]
    return {
        "versions": versions,
        "platform": device.platform,
        "device_kind": device.device_kind,
        "x64": bool(jax.config.read("jax_enable_x64")),
        "source": source_digest(),
    }


def notice(message: str) -> None:
    """Warn with ``message`` as one line (a ``UserWarning`` from "jaxenvs", with no source
    line after it): what a damaged or unwritable cache costs, never an error."""
    warnings.warn_explicit(message, UserWarning, "jaxenvs", 0)


def _aval_text(tree: Any) -> list[str]:
    """``path: dtype[shape]`` per leaf (the treedef's own text holds object addresses)."""
    leaves = jax.tree_util.tree_flatten_with_path(tree)[0]
    return [f"{jax.tree_util.keystr(p)}: {x.dtype}{list(x.shape)}" for p, x in leaves]


def program_key(name: str, config: Mapping[str, Any], args: tuple[Any, ...]) -> str:
    """The hex key of a program: name, config, argument avals and tree, environment."""
    record = {
        "name": name,
        "config": config,
        "args": _aval_text(args),
        "env": _environment(),
    }
    return hashlib.sha256(json.dumps(record, sort_keys=True, default=str).encode()).hexdigest()


@dataclasses.dataclass(frozen=True)
class Program:
    """A loaded or freshly exported program.

    ``call`` (or calling the program) takes and returns the same pytrees as the original
    function; ``jitted`` is the jitted function behind it (``.lower(...).compile()``
    works on it); ``out_shape`` is the output as ``jax.ShapeDtypeStruct`` leaves;
    ``loaded`` says whether it came from disk. ``jitted`` is compiled with jaxenvs' XLA
    options, which XLA takes only on an outermost ``jit``: call the program outside any
    trace, and ask :meth:`eval_shape` (not ``jax.eval_shape``) for its output's shapes.
    """

    jitted: Any
    out_shape: Any
    loaded: bool

    def call(self, *args: Any) -> Any:
        """Run the program. Weakly typed inputs (e.g. from Python scalars in another
        jitted function's output) are made strong first: the module's inputs are, and a
        weak input would make ``jit`` trace and compile the program a second time."""
        return self.jitted(*jax.tree.map(_strong, args))

    def __call__(self, *args: Any) -> Any:
        return self.call(*args)

    def eval_shape(self, *args: Any) -> Any:
        """The output's shapes for ``args`` (arrays or ``jax.ShapeDtypeStruct``s)."""
        return self.jitted.eval_shape(*args)


def _strong(x: Any) -> Any:
    if getattr(x, "weak_type", False):
        return jax.lax.convert_element_type(x, x.dtype)
    return x


class _NotDescribable(Exception):
    pass


def _describe(tree: Any, known: list[Any]) -> Any:
    """JSON for the treedef ``tree``: builtin containers and leaves spelt out, any subtree
    equal to one of the ``known`` treedefs referenced by index (custom pytree nodes such as
    ``mjx.Data`` carry static data that JSON cannot hold, so they must be known)."""
    for i, k in enumerate(known):
        if tree == k:
            return {"known": i}
    if jax.tree_util.treedef_is_leaf(tree):
        return "*"
    node = tree.node_data()
    kind = None if node is None else node[0]
    children = [_describe(c, known) for c in tree.children()]
    if kind is tuple:
        return {"tuple": children}
    if kind is list:
        return {"list": children}
    if kind is dict and all(isinstance(k, str) for k in node[1]):
        return {"dict": [list(node[1]), children]}
    if kind is type(None):
        return {"none": True}
    raise _NotDescribable(f"{kind} is neither a builtin container nor a known structure")


def _example(desc: Any, known: list[Any]) -> Any:
    """A pytree (leaves 0) with the structure :func:`_describe` wrote as ``desc``."""
    if desc == "*":
        return 0
    if "known" in desc:
        tree = known[desc["known"]]
        return jax.tree.unflatten(tree, [0] * tree.num_leaves)
    if "tuple" in desc:
        return tuple(_example(c, known) for c in desc["tuple"])
    if "list" in desc:
        return [_example(c, known) for c in desc["list"]]
    if "dict" in desc:
        keys, children = desc["dict"]
        return {k: _example(c, known) for k, c in zip(keys, children, strict=True)}
    return None


def _export(fn: Callable[..., Any], args: tuple[Any, ...]) -> tuple[Any, Any]:
    """``jax.export`` of ``fn`` over flat leaves (custom pytree nodes stay out of the file)."""
    leaves, in_tree = jax.tree.flatten(args)
    box: list[Any] = []

    def flat(*xs: Any) -> list[Any]:
        out_leaves, out_tree = jax.tree.flatten(fn(*jax.tree.unflatten(in_tree, list(xs))))
        box.append(out_tree)
        return out_leaves

    from jaxenvs.physics import native

    # the C engine's native call: stored programs name the model by its digest, and are
    # stored only where the native engine is loaded (jaxenvs.run.programs)
    checks = [jax.export.DisabledSafetyCheck.custom_call(native.TARGET)]
    exported = jax.export.export(jax.jit(flat), disabled_checks=checks)(*leaves)
    return exported, box[0]


def _wrap(exported: Any, in_tree: Any, out_tree: Any, loaded: bool) -> Program:
    @jit
    def call(*args: Any) -> Any:
        leaves, tree = jax.tree.flatten(args)
        if tree != in_tree:
            raise ValueError(f"arguments {tree} do not match the stored program's {in_tree}")
        return jax.tree.unflatten(out_tree, exported.call(*leaves))

    shapes = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in exported.out_avals]
    return Program(call, jax.tree.unflatten(out_tree, shapes), loaded)


#: file layout: MAGIC, the SHA-256 digest (32 bytes) of everything after it, a
#: little-endian u32 header length, the JSON header (name, key, output structure), the module
MAGIC = b"jaxenvs-program-2\n"
_DIGEST = 32


class DamagedProgram(ValueError):
    """A stored program file does not verify (truncated, altered, or another key's)."""


def _pack(key: str, name: str, out: Any, module: bytes) -> bytes:
    """The file content of a stored program (see :data:`MAGIC` for the layout)."""
    header = json.dumps({"name": name, "key": key, "out": out}).encode()
    body = struct.pack("<I", len(header)) + header + module
    return MAGIC + hashlib.sha256(body).digest() + body


def _unpack(blob: bytes, key: str) -> tuple[dict[str, Any], bytes]:
    """``(header, module)`` of a file written by :func:`_pack` for ``key``.

    Raises :class:`DamagedProgram` unless the magic, the digest and the key all match.
    """
    start = len(MAGIC) + _DIGEST
    if not blob.startswith(MAGIC) or len(blob) < start + 4:
        raise DamagedProgram("not a stored program of this version")
    body = blob[start:]
    if hashlib.sha256(body).digest() != blob[len(MAGIC) : start]:
        raise DamagedProgram("digest mismatch (truncated or altered)")
    (size,) = struct.unpack("<I", body[:4])
    header = json.loads(body[4 : 4 + size])
    if not isinstance(header, dict) or header.get("key") != key:
        raise DamagedProgram("the file holds another key's program")
    return header, body[4 + size :]


def _read(blob: bytes, key: str, known: list[Any]) -> tuple[Any, Any]:
    """``(exported, out_tree)`` of a stored file's content ``blob`` for ``key``; raises
    when it does not verify or deserialise."""
    header, module = _unpack(blob, key)
    exported = jax.export.deserialize(bytearray(module))
    example = _example(header["out"], known)
    out_tree = jax.tree.structure(example)
    if len(jax.tree.leaves(example)) != len(exported.out_avals):
        raise DamagedProgram("output structure does not match the module")
    return exported, out_tree


def _load(path: Path, key: str, known: list[Any], in_tree: Any, shapes: Any) -> Program | None:
    """The verified program stored at ``path``; ``None`` when there is none or it is
    damaged (then the file is removed, with one warning).

    The module is lowered here, not at the caller's first call, so that a module which
    does not deserialise into StableHLO is caught by this fallback too.
    """
    try:
        blob = path.read_bytes()
    except OSError:  # absent, or a store that cannot be read (its write will say so)
        return None
    try:
        exported, out_tree = _read(blob, key, known)
        program = _wrap(exported, in_tree, out_tree, loaded=True)
        program.jitted.lower(*shapes)
        return program
    except Exception as err:  # noqa: BLE001 - any damage means: discard and trace again
        detail = str(err).strip().splitlines()[0][:200] if str(err).strip() else ""
        notice(
            f"discarding damaged stored program {path.name} ({type(err).__name__}: "
            f"{detail}); tracing it again"
        )
        with contextlib.suppress(OSError):
            path.unlink()
        return None


def load_or_export(
    fn: Callable[..., Any],
    args: tuple[Any, ...],
    *,
    name: str,
    config: Mapping[str, Any],
    directory: str | Path,
    known: tuple[Any, ...] = (),
) -> Program:
    """``fn`` (pure, jittable) as a :class:`Program`, loaded from ``directory`` if stored.

    Args:
      fn: the function; everything it closes over must be determined by ``config`` and
        the package's files (see the module docstring).
      args: example arguments (arrays or ``jax.ShapeDtypeStruct``; only shapes, dtypes
        and the tree structure are used).
      name: what the program is (part of the key and the file name).
      config: JSON-able settings that, with the package files, determine ``fn``.
      directory: where programs are stored (created).
      known: example pytrees, cheap to build, whose structures the output reuses (e.g.
        the input state for a step-like function). Every custom pytree node of the
        output (anything but tuples, lists, string-keyed dicts and None) must sit in a
        subtree equal to one of them; if not, the program is returned but not stored.
    """
    directory = Path(directory)
    in_tree = jax.tree.structure(args)
    known_trees = [jax.tree.structure(k) for k in known]
    key = program_key(name, {"config": config, "known": [_aval_text(k) for k in known]}, args)
    path = directory / f"{name}-{key}.jaxexport"
    shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), args)
    stored = _load(path, key, known_trees, in_tree, shapes)
    if stored is not None:
        return stored
    exported, out_tree = _export(fn, shapes)
    try:
        blob = _pack(key, name, _describe(out_tree, known_trees), bytes(exported.serialize()))
        directory.mkdir(parents=True, exist_ok=True)
        files.write_bytes(path, blob)
    except (OSError, ImportError, _NotDescribable) as err:
        # the store only saves time; the program itself is fine. (Serialising needs the
        # ``flatbuffers`` package, a dependency of jaxenvs.)
        notice(f"could not store program {path}: {err}")
    return _wrap(exported, in_tree, out_tree, loaded=False)
