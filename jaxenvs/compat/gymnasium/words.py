"""The facade's state representation: a State as a few flat buffers of 32-bit words.

Flattening the ~100-leaf pytree of an ``mjx.Data`` in Python costs far more than a small
env's physics step, so the facade keeps an env's (or a batch's) State as the buffers of a
:class:`Words` layout; only the jitted functions see the tree. The leaves the host reads
after every step (:data:`REPORTED`, then the info keys) come first, so a step's results are
read from the first buffer(s) of the new state without a separate output.
"""

from __future__ import annotations

import functools
import struct
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxenvs.core import State

#: XLA's CPU runtime runs a program thunk after thunk on the calling thread only when every
#: buffer it touches holds at most this many bytes; one larger buffer sends ready thunks to
#: its thread pool, which costs a single env's small step more in thread hand-offs (~50 us
#: on 2 cores) than the step itself.
SEQUENTIAL_BYTES = 512
#: the leaves of a State every step reports to the host, in this order (then the task's
#: info keys)
REPORTED = ("obs", "reward", "terminated", "truncated")

Bufs = tuple[jax.Array, ...]


def _is_word(leaf: Any) -> bool:
    """True for a leaf stored as 32-bit words: 4-byte dtypes, bools, uint32 key data."""
    dtype = leaf.dtype
    if jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key):
        return _key_data(leaf).dtype == jnp.uint32
    return dtype == jnp.bool_ or np.dtype(dtype).itemsize == 4


def _key_data(leaf: Any) -> jax.ShapeDtypeStruct:
    """Shape and dtype of the data of a PRNG key (array or ShapeDtypeStruct)."""
    return jax.eval_shape(jax.random.key_data, leaf)


def _to_words(leaf: jax.Array, lead: tuple[int, ...]) -> jax.Array:
    """A 32-bit leaf as float32 words of shape ``(*lead, -1)``: floats as they are, bools
    as 0.0 / 1.0, integers and key data by their bits."""
    if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        leaf = jax.random.key_data(leaf)
    if leaf.dtype == jnp.bool_:
        leaf = leaf.astype(jnp.float32)
    elif leaf.dtype != jnp.float32:
        leaf = jax.lax.bitcast_convert_type(leaf, jnp.float32)
    return jnp.reshape(leaf, (*lead, -1))


class Words:
    """A State's layout as a few flat float32 buffers (one env, or a batch of them).

    Every 32-bit leaf (float32, int32, uint32, bool, the PRNG key's data) is stored in
    float32 words (float32 leaves, most of the state, need no kernel to pack); leaves of
    other sizes (float64 under x64) travel in buffers per dtype after the words. Each
    buffer in and out of a jitted call costs ~1 us of dispatch, so the state travels in as
    few buffers as the rule below allows. The reported leaves come first.

    ``lead`` is the batch shape: ``()`` for one env, whose buffers each hold at most
    :data:`SEQUENTIAL_BYTES` so that its step runs on the calling thread (and the reported
    leaves share the first buffer with other leaves); ``(N,)`` for a batch, whose buffers
    are ``(N, words)`` and larger than that limit at any useful size: there the reported
    leaves have the first buffer to themselves (the one the host reads) and every other
    word is in the second.

    Args:
      example: the State's shapes and dtypes, every leaf with the ``lead`` axes first.
      info_keys: the info keys reported after :data:`REPORTED`.
      lead: the batch shape.
      final_obs: also report ``info["final_obs"]`` (after ``obs``).
    """

    def __init__(
        self,
        example: State,
        info_keys: tuple[str, ...],
        lead: tuple[int, ...] = (),
        final_obs: bool = False,
    ) -> None:
        with_paths, self.treedef = jax.tree_util.tree_flatten_with_path(example)
        leaves = [x for _, x in with_paths]
        self.lead = lead
        self.examples = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
        index = {jax.tree_util.keystr(path): i for i, (path, _) in enumerate(with_paths)}
        #: the PRNG implementation of each key leaf (read from a traced key)
        self.key_impls: dict[int, Any] = {}
        for i, x in enumerate(self.examples):
            if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
                jax.eval_shape(functools.partial(self._grab_impl, i), x)
        vectors = [".obs"] + ([".info['final_obs']"] if final_obs else [])
        scalars = [f".{name}" for name in REPORTED[1:]] + [f".info[{k!r}]" for k in info_keys]
        first = [index[path] for path in vectors + scalars]
        if not all(_is_word(leaves[i]) and len(self._per_env(i).shape) <= 1 for i in first):
            raise TypeError("a reported leaf of the env's State is not a 32-bit scalar or vector")
        if any(self._words(i) != 1 for i in first[len(vectors) :]):
            raise TypeError("a reported scalar of the env's State has more than one element")
        rest = [i for i in range(len(leaves)) if i not in set(first)]
        words = [i for i in rest if _is_word(leaves[i])]
        others: dict[str, list[int]] = {}
        for i in rest:
            if not _is_word(leaves[i]):
                others.setdefault(str(leaves[i].dtype), []).append(i)
        #: leaf indices per buffer: the words' buffers, then the other dtypes'
        self.chunks: list[list[int]]
        if lead:
            self.chunks = [first] + ([words] if words else [])
            self.chunks += [others[name] for name in sorted(others)]
            self.num_words = 1 + bool(words)
        else:
            self.chunks = self._split(first + words, 4)
            self.num_words = len(self.chunks)
            for name in sorted(others):
                self.chunks += self._split(others[name], np.dtype(name).itemsize)
        #: buffers holding the reported leaves (their words lie at the start of these)
        self.num_reported = self._buffers_holding(len(first))
        # columns: obs [| final_obs] | reward | terminated | truncated | info...
        at = 0
        self.columns: dict[str, slice] = {}
        for name, i in zip(["obs", "final_obs"], first[: len(vectors)], strict=False):
            self.columns[name] = slice(at, at + self._words(i))
            at += self._words(i)
        self.scalars = slice(at, at + len(scalars))
        self.obs = self.columns["obs"]
        #: (key, numpy dtype kind: "b" bool, "i" / "u" integer, "f" float) per info key
        self.info = [
            (k, np.dtype(leaves[i].dtype).kind)
            for k, i in zip(info_keys, first[len(vectors) + 3 :], strict=True)
        ]
        # one env's scalars read in one call (:meth:`report`): float32 words as floats,
        # integer leaves by their bits
        codes = "".join({"i": "i", "u": "I"}.get(kind, "f") for _, kind in self.info)
        self._scalar_words = struct.Struct(f"=fff{codes}")
        self._scalar_offset = 4 * self.scalars.start  # bytes: the words are float32
        self._info_keys = tuple(k for k, _ in self.info)
        self._bool_keys = tuple(k for k, kind in self.info if kind == "b")

    def _per_env(self, i: int) -> jax.ShapeDtypeStruct:
        x = self.examples[i]
        return jax.ShapeDtypeStruct(x.shape[len(self.lead) :], x.dtype)

    def _words(self, i: int) -> int:
        """Elements leaf ``i`` takes per env in its buffer (words for 32-bit leaves)."""
        x = self.examples[i]
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            x = _key_data(x)
        shape = x.shape
        return int(np.prod(shape[len(self.lead) :], dtype=np.int64))

    def _split(self, order: list[int], itemsize: int) -> list[list[int]]:
        """``order`` cut into runs of at most SEQUENTIAL_BYTES (a larger leaf: alone)."""
        limit = SEQUENTIAL_BYTES // itemsize
        chunks: list[list[int]] = []
        filled = 0
        for i in order:
            size = self._words(i)
            if not chunks or filled + size > limit:
                chunks.append([])
                filled = 0
            chunks[-1].append(i)
            filled += size
        return chunks

    def _buffers_holding(self, count: int) -> int:
        """How many leading buffers hold the first ``count`` leaves of the order."""
        seen = 0
        for c, chunk in enumerate(self.chunks):
            seen += len(chunk)
            if seen >= count:
                return c + 1
        raise AssertionError("the reported leaves are not in the buffers")

    def _grab_impl(self, i: int, key: jax.Array) -> jax.Array:
        self.key_impls[i] = jax.random.key_impl(key)
        return key

    def pack(self, state: State) -> Bufs:
        """The state's buffers (traced inside the jitted functions)."""
        leaves = jax.tree.leaves(state)
        lead = self.lead
        out = [
            jnp.concatenate([_to_words(leaves[i], lead) for i in chunk], axis=-1)
            for chunk in self.chunks[: self.num_words]
        ]
        out += [
            jnp.concatenate([jnp.reshape(leaves[i], (*lead, -1)) for i in chunk], axis=-1)
            for chunk in self.chunks[self.num_words :]
        ]
        return tuple(out)

    def unpack(self, bufs: Bufs) -> State:
        """The State held by ``bufs`` (bit for bit what :meth:`pack` was given)."""
        leaves: list[Any] = [None] * len(self.examples)
        for c, (buf, chunk) in enumerate(zip(bufs, self.chunks, strict=True)):
            at = 0
            for i in chunk:
                x, size = self.examples[i], self._words(i)
                piece = buf[..., at : at + size]
                at += size
                if c >= self.num_words or x.dtype == jnp.float32:
                    leaves[i] = jnp.reshape(piece, x.shape)
                elif jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
                    data = jax.lax.bitcast_convert_type(piece, _key_data(x).dtype)
                    data = jnp.reshape(data, _key_data(x).shape)
                    leaves[i] = jax.random.wrap_key_data(data, impl=self.key_impls[i])
                elif x.dtype == jnp.bool_:
                    leaves[i] = jnp.reshape(piece != 0, x.shape)
                else:
                    value = jax.lax.bitcast_convert_type(piece, x.dtype)
                    leaves[i] = jnp.reshape(value, x.shape)
        return jax.tree.unflatten(self.treedef, leaves)

    def _host_words(self, bufs: Bufs) -> np.ndarray:
        """The reported buffers on the host, one array (the only device-to-host copy)."""
        if self.num_reported == 1:
            return np.asarray(bufs[0])
        return np.concatenate([np.asarray(b) for b in bufs[: self.num_reported]], axis=-1)

    def report(self, bufs: Bufs) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One env's ``(obs, reward, terminated, truncated, info)`` read from its buffers
        (Python scalars, a fresh numpy obs)."""
        words = self._host_words(bufs)
        values = self._scalar_words.unpack_from(words.data, self._scalar_offset)
        info = dict(zip(self._info_keys, values[3:], strict=True))
        for key in self._bool_keys:
            info[key] = info[key] != 0.0
        obs = words[self.obs].copy()
        return obs, values[0], values[1] != 0.0, values[2] != 0.0, info

    def report_batch(self, bufs: Bufs) -> dict[str, np.ndarray]:
        """A batch's reported leaves as fresh numpy arrays: ``obs`` (and ``final_obs``)
        float32, ``reward`` float64, ``terminated`` / ``truncated`` bool, and per info key
        bool, int64 or float64 (the dtypes ``SyncVectorEnv`` gives Python scalars)."""
        words = self._host_words(bufs)
        out = {name: np.array(words[:, cols]) for name, cols in self.columns.items()}
        scalars = words[:, self.scalars]
        out["reward"] = scalars[:, 0].astype(np.float64)
        out["terminated"] = scalars[:, 1] != 0.0
        out["truncated"] = scalars[:, 2] != 0.0
        for j, (key, kind) in enumerate(self.info, start=3):
            column = scalars[:, j]
            if kind == "f":
                out[key] = column.astype(np.float64)
            elif kind == "b":
                out[key] = column != 0.0
            else:
                out[key] = column.view(np.uint32 if kind == "u" else np.int32).astype(np.int64)
        return out
