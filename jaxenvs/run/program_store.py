"""Traced programs kept on disk (``jax.export``), beside the compile cache.

JAX's persistent compilation cache (:mod:`jaxenvs.run.compile_cache`) lets a second run skip
XLA's compile, but not tracing and lowering: the Python that builds a run's init, chunk
and evaluator runs again in every process, and a cache hit still lowers the program,
since the cache's key is the lowered module. On two cores that was about 2 s of the main
job's warm run (``benchmarks/NOTES.md``, "The traced-program store, again"). This module
exports a traced program with ``jax.export`` the first time and, on later runs, loads it
instead of tracing: a small wrapper around the stored module is lowered, and its compile
hits the persistent cache as before.

A stored program is looked up by a key that covers everything the trace depends on: a
caller-chosen name and config, the argument shapes, dtypes and tree structure, the
versions of jax, jaxlib, mujoco, mujoco-mjx, flax and optax, the backend and device kind,
the JAX settings that change a trace (:data:`TRACE_SETTINGS`), and a digest of every
source, model and config file of the jaxenvs package (read once per process: a process
whose package files change under it keys new programs by the old digest). Anything else
a program closes over must be in the caller's config:
:func:`jaxenvs.run.programs.store_settings` stores only the programs of tasks, trainers
and configs defined in this package, and puts the engine's settings in the config.

Trust. A file holds the serialised module, a JSON description of the output's tree
structure (no pickle: custom pytree nodes in the output are described by reference to
example structures the caller passes in, ``known``), its own key and a SHA-256 digest of
its content, and is written atomically. A file that is truncated, altered, stored under
another key's name, or whose module does not deserialise is discarded with one warning;
one that does not lower in this process is left with one warning; either way the program
is traced and stored again: a damaged store costs a trace, never a failed run or another
program. The store is bounded (:data:`MAX_BYTES`, apart from the compile cache's own
limit), the least recently loaded programs removed first.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import os
import struct
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax

from jaxenvs import files
from jaxenvs.run.compile_cache import notice

#: subdirectory of the compile-cache directory that holds stored programs
SUBDIR = "programs"
#: the ``jaxenvs`` package (this file is ``jaxenvs/run/program_store.py``)
_PACKAGE = Path(__file__).resolve().parents[1]
_SOURCE_SUFFIXES = (".py", ".xml", ".yaml", ".cc", ".h", ".png", ".stl", ".obj")
_VERSIONED = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax")
#: JAX settings that change what a trace produces, part of every key
TRACE_SETTINGS = (
    "jax_enable_x64",
    "jax_default_prng_impl",
    "jax_threefry_partitionable",
    "jax_default_matmul_precision",
    "jax_numpy_dtype_promotion",
    "jax_numpy_rank_promotion",
    "jax_debug_nans",
    "jax_debug_infs",
    "jax_use_shardy_partitioner",
    "jax_softmax_custom_jvp",
    "jax_enable_custom_prng",
    "jax_legacy_prng_key",
    "jax_threefry_gpu_kernel_lowering",
)
#: file layout: MAGIC, the SHA-256 digest (32 bytes) of everything after it, a
#: little-endian u32 header length, the JSON header (name, key, output structure), the module
MAGIC = b"jaxenvs-program-3\n"
_DIGEST = 32
#: the store's size limit: past it, the least recently used programs are removed (a
#: program's file is touched each time it is loaded)
MAX_BYTES = 512 * 1024**2


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
def _versions() -> tuple[tuple[str, str | None], ...]:
    from jaxenvs.physics.native import installed_version

    return tuple((name, installed_version(name)) for name in _VERSIONED)


def _environment() -> dict[str, Any]:
    """The versions, device, trace settings and package digest a key covers (the
    versions and the digest read once per process)."""
    device = jax.devices()[0]
    return {
        "versions": dict(_versions()),
        "platform": device.platform,
        "device_kind": device.device_kind,
        "settings": {name: str(getattr(jax.config, name, None)) for name in TRACE_SETTINGS},
        "source": source_digest(),
    }


def _aval_text(tree: Any) -> list[str]:
    """``path: dtype[shape]`` per leaf, weak types marked (the treedef's own text holds
    object addresses)."""
    leaves = jax.tree_util.tree_flatten_with_path(tree)[0]
    return [
        f"{jax.tree_util.keystr(p)}: {x.dtype}{list(x.shape)}"
        + (" weak" if getattr(x, "weak_type", False) else "")
        for p, x in leaves
    ]


def program_key(name: str, config: Mapping[str, Any], args: tuple[Any, ...]) -> str:
    """The hex key of a program: name, config, argument avals and tree, environment."""
    record = {"name": name, "config": config, "args": _aval_text(args), "env": _environment()}
    return hashlib.sha256(json.dumps(record, sort_keys=True, default=str).encode()).hexdigest()


def _shapes(tree: Any) -> Any:
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), tree)


@dataclasses.dataclass(frozen=True)
class Program:
    """A loaded or freshly exported program, called like the function it was made of.

    ``jitted`` is the jitted wrapper around the exported module (compiled with the XLA
    options of the ``jit`` it was given, which XLA takes only on an outermost ``jit``:
    call the program outside any trace); ``in_shape`` and ``out_shape`` are its
    arguments and output as ``jax.ShapeDtypeStruct`` leaves; ``loaded`` says whether it
    came from disk.
    """

    jitted: Any
    in_shape: Any
    out_shape: Any
    loaded: bool

    def __call__(self, *args: Any) -> Any:
        """Run the program. Weakly typed inputs are made strong first, as the module's
        are: a weak input would make ``jit`` trace and compile the wrapper again."""
        return self.jitted(*jax.tree.map(strong, args))

    def eval_shape(self, *args: Any) -> Any:
        """The output's shapes for ``args`` (arrays or ``jax.ShapeDtypeStruct``s), which
        must have the stored arguments' structure, shapes and dtypes; no trace."""
        tree: Any = jax.tree.structure(args)
        same_tree = tree == jax.tree.structure(self.in_shape)
        if not same_tree or _aval_text(_shapes(args)) != _aval_text(self.in_shape):
            raise ValueError("arguments do not match the stored program's")
        return self.out_shape

    def lower(self, *args: Any) -> Any:
        """The wrapper lowered for ``args``."""
        return self.jitted.lower(*jax.tree.map(strong, args))


def strong(x: Any) -> Any:
    """``x`` without its weak type (an array converted, a ``ShapeDtypeStruct`` rebuilt)."""
    if not getattr(x, "weak_type", False):
        return x
    if isinstance(x, jax.ShapeDtypeStruct):
        return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding)
    return jax.lax.convert_element_type(x, x.dtype)


def _export(fn: Callable[..., Any], shapes: tuple[Any, ...]) -> tuple[Any, Any, Any]:
    """``(exported, in_tree, out_tree)``: ``jax.export`` of ``fn`` over flat leaves."""
    leaves, in_tree = jax.tree.flatten(shapes)
    box: list[Any] = []

    def flat(*xs: Any) -> list[Any]:
        out_leaves, out_tree = jax.tree.flatten(fn(*jax.tree.unflatten(in_tree, list(xs))))
        box.append(out_tree)
        return out_leaves

    from jaxenvs.physics import native

    # the C engine's native call: a stored program names the model it steps by the
    # model's digest, and is stored only where the native engine is loaded
    checks = [jax.export.DisabledSafetyCheck.custom_call(native.TARGET)]
    exported = jax.export.export(jax.jit(flat), disabled_checks=checks)(*leaves)
    return exported, in_tree, box[0]


def _wrap(
    exported: Any, in_tree: Any, out_tree: Any, jit: Callable[..., Any], loaded: bool
) -> Program:
    def call(*args: Any) -> Any:
        leaves, tree = jax.tree.flatten(args)
        if tree != in_tree:
            raise ValueError(f"arguments {tree} do not match the stored program's {in_tree}")
        return jax.tree.unflatten(out_tree, exported.call(*leaves))

    def structs(avals: Any, tree: Any) -> Any:
        return jax.tree.unflatten(tree, [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in avals])

    in_shape = structs(exported.in_avals, in_tree)
    return Program(jit(call), in_shape, structs(exported.out_avals, out_tree), loaded)


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


class DamagedProgram(ValueError):
    """A stored program file does not verify (truncated, altered, or another key's)."""


def _pack(key: str, name: str, out: Any, module: bytes) -> bytes:
    """The file content of a stored program (see :data:`MAGIC` for the layout)."""
    header = json.dumps({"name": name, "key": key, "out": out}).encode()
    body = struct.pack("<I", len(header)) + header + module
    return MAGIC + hashlib.sha256(body).digest() + body


def _unpack(blob: bytes, key: str) -> tuple[dict[str, Any], bytes]:
    """``(header, module)`` of a file written by :func:`_pack` for ``key``; raises
    :class:`DamagedProgram` unless the magic, the digest and the key all match."""
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


def _load(
    path: Path, key: str, in_tree: Any, known: list[Any], jit: Callable[..., Any]
) -> Program | None:
    """The verified program stored at ``path``; ``None`` when there is none, when it is
    damaged (then the file is removed, with one warning), or when it does not lower in
    this process (one warning; the caller traces it again and stores it over this one).
    The wrapper is lowered here, not at the caller's first call, so that the caller's
    fallback covers that too."""
    try:
        blob = path.read_bytes()
    except OSError:  # absent, or a store that cannot be read (its write will say so)
        return None
    try:
        header, module = _unpack(blob, key)
        exported = jax.export.deserialize(bytearray(module))
        out_tree: Any = jax.tree.structure(_example(header["out"], known))
        leaves = (in_tree.num_leaves, out_tree.num_leaves)
        if leaves != (len(exported.in_avals), len(exported.out_avals)):
            raise DamagedProgram("tree structures do not match the module")
    except Exception as err:  # noqa: BLE001 - any damage means: discard and trace again
        why = _one_line(err)
        notice(f"discarding damaged stored program {path.name} ({why}); tracing it again")
        with contextlib.suppress(OSError):
            path.unlink()
        return None
    program = _wrap(exported, in_tree, out_tree, jit, loaded=True)
    try:
        program.lower(*program.in_shape)
    except Exception as err:  # noqa: BLE001 - a setting of this process the key missed
        notice(f"stored program {path.name} does not lower here ({_one_line(err)}); tracing it")
        return None
    with contextlib.suppress(OSError):
        os.utime(path)  # recently used (prune)
    return program


def _one_line(err: BaseException) -> str:
    """``Type: first line of the message`` (at most 200 characters of it)."""
    text = str(err).strip()
    return f"{type(err).__name__}: {text.splitlines()[0][:200] if text else ''}"


def load_or_export(
    fn: Callable[..., Any],
    args: tuple[Any, ...],
    *,
    name: str,
    config: Mapping[str, Any],
    directory: str | Path,
    jit: Callable[..., Any],
    known: tuple[Any, ...] = (),
) -> Program | None:
    """``fn`` (pure, jittable) as a :class:`Program` jitted with ``jit``, loaded from
    ``directory`` if stored there, else traced, exported and stored; ``None`` where ``fn``
    cannot be a stored program (the caller compiles it as usual): arguments with a
    weakly typed leaf (the module would be traced on strong types), or a function
    ``jax.export`` refuses (a host callback, a foreign custom call; one warning).

    Args:
      fn: the function; everything it closes over must be determined by ``config`` and
        the package's files (see the module docstring).
      args: example arguments (arrays or ``jax.ShapeDtypeStruct``; only shapes, dtypes
        and the tree structure are used).
      name: what the program is (part of the key and of the file name).
      config: JSON-able settings that, with the package files, determine ``fn``.
      directory: where programs are stored (created).
      jit: how the wrapper is jitted (:func:`jaxenvs.core.xla.jit` or ``jit_once``).
      known: example pytrees whose structures the output reuses (e.g. the input state of a
        step-like function). Every custom pytree node of the output (anything but tuples,
        lists, string-keyed dicts and None) must sit in a subtree equal to one of them;
        if not, the program is returned but not stored, with one warning.

    A store that cannot be written, or an output that cannot be described, leaves the
    program working, unstored, with one warning.
    """
    if any(getattr(x, "weak_type", False) for x in jax.tree.leaves(args)):
        return None  # exported on strong types, it would not be the program ``fn`` traces
    directory = Path(directory)
    in_tree = jax.tree.structure(args)
    known_trees = [jax.tree.structure(k) for k in known]
    key = program_key(name, {"config": config, "known": [_aval_text(k) for k in known]}, args)
    path = directory / f"{name}-{key[:32]}.jaxexport"
    stored = _load(path, key, in_tree, known_trees, jit)
    if stored is not None:
        return stored
    try:
        exported, in_tree, out_tree = _export(fn, _shapes(args))
    except Exception as err:  # noqa: BLE001 - e.g. a host callback, which jax.export refuses
        notice(f"program {name} is not stored ({_one_line(err)}); compiled as usual")
        return None
    program = _wrap(exported, in_tree, out_tree, jit, loaded=False)
    try:
        blob = _pack(key, name, _describe(out_tree, known_trees), bytes(exported.serialize()))
        directory.mkdir(parents=True, exist_ok=True)
        files.write_bytes(path, blob)
        prune(directory, MAX_BYTES, keep=path)
    except Exception as err:  # noqa: BLE001 - the store only saves time; the program is fine
        notice(f"could not store program {path}: {_one_line(err)}")
    return program


def prune(directory: Path, max_bytes: int, keep: Path | None = None) -> list[Path]:
    """Remove the least recently used stored programs in ``directory`` (oldest
    modification time first; loading one touches it) until the rest take at most
    ``max_bytes``, never ``keep`` (the program just stored) nor another process's file
    still being written (a dot-named temporary); returns what was removed. A file another
    process removes first is skipped."""
    entries = []
    for path in directory.glob("*.jaxexport"):
        if path.name.startswith(".") or path == keep:
            continue
        with contextlib.suppress(OSError):
            stat = path.stat()
            entries.append((stat.st_mtime_ns, stat.st_size, path))
    entries.sort()
    total = sum(size for _, size, _ in entries)
    if keep is not None:
        with contextlib.suppress(OSError):
            total += keep.stat().st_size
    removed = []
    for _, size, path in entries:
        if total <= max_bytes:
            break
        with contextlib.suppress(OSError):
            path.unlink()
            removed.append(path)
        total -= size
    return removed
