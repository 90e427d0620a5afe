"""Gymnasium facade: every jaxenvs id as a ``gymnasium.Env`` and a ``gymnasium.vector.VectorEnv``.

After ``import jaxenvs`` each registered id ``X`` is also registered with Gymnasium as
``jaxenvs/X`` (with ``max_episode_steps`` = the task's episode length and the id's
``reward_threshold``), including ids registered later through :func:`jaxenvs.register`::

    env = gymnasium.make("jaxenvs/CartPole-v0", render_mode="rgb_array")
    envs = gymnasium.make_vec("jaxenvs/CartPole-v0", num_envs=1024,
                              vectorization_mode="vector_entry_point")

Keyword arguments of ``make``/``make_vec`` other than ``render_mode``, ``width``,
``height``, ``camera`` (and ``randomize`` for the vector env) override fields of the
task's config, as in :func:`jaxenvs.make`.

:class:`JaxEnv` (one env): numpy float32 observations, Python scalars in the 5-tuple,
Gymnasium seeding (``reset(seed=)`` seeds ``np_random``, which draws the JAX key of every
reset). ``reset`` and ``step`` are jitted once per task config and shared by every
instance. The env keeps its state as a few small buffers of 32-bit words (:class:`_Words`):
a step donates them to one jitted call, and reads the observation, reward, flags and info
from the first of the new ones. Small buffers keep XLA's CPU runtime on the calling thread
(:data:`SEQUENTIAL_BYTES`), where a single small env's step costs ~3x less.

:class:`JaxVectorEnv` (N envs): one jitted, vmapped :class:`~jaxenvs.core.BatchedEnv`
step, one device-to-host transfer per step. Auto-reset is ``AutoresetMode.SAME_STEP``:
an env whose episode ended in this step comes back already reset (a fresh random start);
``infos["final_obs"]`` (an object array, ``None`` for envs that did not finish) holds the
finished episode's last observation and ``infos["final_info"]`` its step info, each with
its ``_``-prefixed mask, exactly as Gymnasium's ``SyncVectorEnv`` does in that mode.
``reset(options={"reset_mask": mask})`` resets only the envs where ``mask`` is True.

Info keys (single env values are Python scalars, vector values arrays with ``_key``
masks): ``nan_actions``, ``diverged`` and the task's metrics (e.g. ``distance``).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import warnings
from collections.abc import Callable
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from jaxenvs import registry
from jaxenvs.core import BatchedEnv, Env, State

PREFIX = "jaxenvs/"
RENDER_MODES = ["rgb_array"]
#: what the entry points declare to ``gymnasium.make``: "human" is listed so that it reaches
#: the constructor (which explains what to do) instead of being silently rerouted.
_DECLARED_MODES = ["rgb_array", "human"]
#: info keys every env reports besides its task metrics.
BASE_INFO_KEYS = ("nan_actions", "diverged")


def gym_id(env_id: str) -> str:
    """The Gymnasium id of a jaxenvs id: ``"jaxenvs/" + env_id``."""
    return PREFIX + env_id


def register_spec(spec: registry.EnvSpec) -> None:
    """Register ``jaxenvs/<spec.id>`` with Gymnasium (replacing an earlier registration)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Gymnasium warns when an id is re-registered
        gymnasium.register(
            id=gym_id(spec.id),
            entry_point=f"{__name__}:JaxEnv",
            vector_entry_point=f"{__name__}:JaxVectorEnv",
            max_episode_steps=int(spec.config.episode_length),
            reward_threshold=spec.reward_threshold,
            kwargs={"env_id": spec.id},
        )


# ----------------------------------------------------------------- compiled functions
@dataclasses.dataclass(frozen=True)
class _Layout:
    """Column layout of the packed array a step sends to the host."""

    obs_size: int
    info_keys: tuple[str, ...]

    @property
    def reward(self) -> int:
        return 2 * self.obs_size

    @property
    def width(self) -> int:
        return 2 * self.obs_size + 3 + len(self.info_keys)


def _pack(state: State, layout: _Layout) -> jax.Array:
    """obs | final_obs | reward | terminated | truncated | info..., float32, last axis."""
    lead = state.reward.shape
    cols = [
        state.obs,
        state.info["final_obs"],
        state.reward[..., None],
        state.terminated[..., None],
        state.truncated[..., None],
    ]
    cols += [jnp.reshape(state.info[k], (*lead, 1)) for k in layout.info_keys]
    return jnp.concatenate([c.astype(jnp.float32) for c in cols], axis=-1)


class _FlatState:
    """Packs a batched State pytree into a few flat buffers (one per dtype) and back.

    Flattening the ~100-leaf pytree of an ``mjx.Data`` in Python costs far more than a
    small env's physics step, so the vector env keeps its state as these buffers and only
    the jitted functions see the tree. ``lead`` is the batch shape, ``(N,)``.
    """

    def __init__(self, example: Any, lead: tuple[int, ...]) -> None:
        leaves, self.treedef = jax.tree.flatten(example)
        self.lead = lead
        self.shapes = [tuple(x.shape[len(lead) :]) for x in leaves]
        groups: dict[str, list[int]] = {}
        for i, leaf in enumerate(leaves):
            groups.setdefault(str(leaf.dtype), []).append(i)
        #: (indices, is_key) per buffer; PRNG key leaves travel as they are.
        self.groups: list[tuple[list[int], bool]] = []
        for name in sorted(groups):
            if name.startswith("key"):
                self.groups += [([i], True) for i in groups[name]]
            else:
                self.groups.append((groups[name], False))

    def pack(self, state: Any) -> tuple[jax.Array, ...]:
        leaves = jax.tree.leaves(state)
        out = []
        for idx, is_key in self.groups:
            if is_key:
                out.append(leaves[idx[0]])
            else:
                parts = [jnp.reshape(leaves[i], (*self.lead, -1)) for i in idx]
                out.append(jnp.concatenate(parts, axis=-1))
        return tuple(out)

    def unpack(self, bufs: tuple[jax.Array, ...]) -> Any:
        leaves: list[Any] = [None] * len(self.shapes)
        for buf, (idx, is_key) in zip(bufs, self.groups, strict=True):
            if is_key:
                leaves[idx[0]] = buf
                continue
            offset = 0
            for i in idx:
                size = int(np.prod(self.shapes[i], dtype=np.int64))
                piece = buf[..., offset : offset + size]
                leaves[i] = jnp.reshape(piece, (*self.lead, *self.shapes[i]))
                offset += size
        return jax.tree.unflatten(self.treedef, leaves)


#: XLA's CPU runtime runs a program thunk after thunk on the calling thread only when every
#: buffer it touches holds at most this many bytes; one larger buffer sends ready thunks to
#: its thread pool, which costs a single env's small step more in thread hand-offs (~50 us
#: on 2 cores) than the step itself.
SEQUENTIAL_BYTES = 512
#: the leaves of a State a single env's step reports to the host, in this order (then the
#: task's info keys)
_REPORTED = ("obs", "reward", "terminated", "truncated")


def _is_word(leaf: Any) -> bool:
    """True for a leaf stored as 32-bit words: 4-byte dtypes, bools, uint32 key data."""
    dtype = leaf.dtype
    if jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key):
        return _key_data(leaf).dtype == jnp.uint32
    return dtype == jnp.bool_ or np.dtype(dtype).itemsize == 4


def _key_data(leaf: Any) -> jax.ShapeDtypeStruct:
    """Shape and dtype of the data of a PRNG key (array or ShapeDtypeStruct)."""
    return jax.eval_shape(jax.random.key_data, leaf)


def _to_words(leaf: jax.Array) -> jax.Array:
    """A 32-bit leaf as float32 words: floats as they are, bools as 0.0 / 1.0, integers and
    key data by their bits."""
    if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        leaf = jax.random.key_data(leaf)
    if leaf.dtype == jnp.bool_:
        return jnp.ravel(leaf).astype(jnp.float32)
    if leaf.dtype != jnp.float32:
        leaf = jax.lax.bitcast_convert_type(leaf, jnp.float32)
    return jnp.ravel(leaf)


def _int(bits: int, kind: str) -> int:
    """The integer whose 32 bits read as int32 are ``bits`` (``kind`` "u": unsigned)."""
    return bits & 0xFFFFFFFF if kind == "u" else bits


class _Words:
    """One env's State as a few flat float32 buffers, each of at most :data:`SEQUENTIAL_BYTES`.

    Every 32-bit leaf (float32, int32, uint32, bool, the PRNG key's data) is stored in
    float32 words (:func:`_to_words`; float32 leaves, most of the state, need no kernel to
    pack), so the state travels in as few buffers as the size limit allows
    (each buffer in and out of a call costs ~1 us of dispatch) and the step's program runs
    sequentially (see :data:`SEQUENTIAL_BYTES`). The reported leaves (:data:`_REPORTED`
    and the info keys) come first, so the host reads a step's results from the first
    buffer(s) of the new state without a separate output. Leaves of other sizes (float64
    under x64) travel in one buffer per dtype after the words.
    """

    def __init__(self, example: State, info_keys: tuple[str, ...]) -> None:
        with_paths, self.treedef = jax.tree_util.tree_flatten_with_path(example)
        leaves = [x for _, x in with_paths]
        self.examples = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
        index = {jax.tree_util.keystr(path): i for i, (path, _) in enumerate(with_paths)}
        #: the PRNG implementation of each key leaf (read from a traced key)
        self.key_impls: dict[int, Any] = {}
        for i, x in enumerate(self.examples):
            if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
                jax.eval_shape(functools.partial(self._grab_impl, i), x)
        reported = [f".{name}" for name in _REPORTED] + [f".info[{k!r}]" for k in info_keys]
        first = [index[path] for path in reported]
        if not all(_is_word(leaves[i]) and leaves[i].ndim <= 1 for i in first):
            raise TypeError("a reported leaf of the env's State is not a 32-bit scalar or vector")
        rest = [i for i in range(len(leaves)) if i not in set(first)]
        order = first + [i for i in rest if _is_word(leaves[i])]
        #: leaf indices per buffer: the words' buffers, then the other dtypes'
        self.chunks = self._split(order, 4)
        self.num_words = len(self.chunks)
        others: dict[str, list[int]] = {}
        for i in rest:
            if not _is_word(leaves[i]):
                others.setdefault(str(leaves[i].dtype), []).append(i)
        for name in sorted(others):
            self.chunks += self._split(others[name], np.dtype(name).itemsize)
        # where each reported value lies in the words of the first buffers
        offsets: dict[int, int] = {}
        buffer_of: dict[int, int] = {}
        at = 0
        for c, chunk in enumerate(self.chunks[: self.num_words]):
            for i in chunk:
                offsets[i], buffer_of[i] = at, c
                at += self._words(i)
        #: buffers holding the reported leaves
        self.num_reported = 1 + max(buffer_of[i] for i in first)
        # obs, then reward, terminated, truncated and the info keys: one word each
        start = offsets[first[0]]
        self.obs = slice(start, start + leaves[first[0]].size)
        self.scalars = slice(self.obs.stop, self.obs.stop + len(first) - 1)
        if any(leaves[i].size != 1 for i in first[1:]):
            raise TypeError("a reported scalar of the env's State has more than one element")
        #: (key, numpy dtype kind: "b" bool, "i" / "u" integer, "f" float) per info key
        self.info = [
            (k, np.dtype(leaves[i].dtype).kind) for k, i in zip(info_keys, first[4:], strict=True)
        ]

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

    def _grab_impl(self, i: int, key: jax.Array) -> jax.Array:
        self.key_impls[i] = jax.random.key_impl(key)
        return key

    def _words(self, i: int) -> int:
        """Elements leaf ``i`` takes in its buffer (words for 32-bit leaves)."""
        x = self.examples[i]
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            return int(np.prod(_key_data(x).shape, dtype=np.int64))
        return int(np.prod(x.shape, dtype=np.int64))

    def pack(self, state: State) -> tuple[jax.Array, ...]:
        leaves = jax.tree.leaves(state)
        out = [
            jnp.concatenate([_to_words(leaves[i]) for i in chunk])
            for chunk in self.chunks[: self.num_words]
        ]
        out += [
            jnp.concatenate([jnp.ravel(leaves[i]) for i in chunk])
            for chunk in self.chunks[self.num_words :]
        ]
        return tuple(out)

    def unpack(self, bufs: tuple[jax.Array, ...]) -> State:
        leaves: list[Any] = [None] * len(self.examples)
        for c, (buf, chunk) in enumerate(zip(bufs, self.chunks, strict=True)):
            at = 0
            for i in chunk:
                x, size = self.examples[i], self._words(i)
                piece = buf[at : at + size]
                at += size
                if c >= self.num_words:
                    leaves[i] = jnp.reshape(piece, x.shape)
                elif jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
                    data = jax.lax.bitcast_convert_type(piece, _key_data(x).dtype)
                    data = jnp.reshape(data, _key_data(x).shape)
                    leaves[i] = jax.random.wrap_key_data(data, impl=self.key_impls[i])
                elif x.dtype == jnp.bool_:
                    leaves[i] = jnp.reshape(piece != 0, x.shape)
                elif x.dtype == jnp.float32:
                    leaves[i] = jnp.reshape(piece, x.shape)
                else:
                    value = jax.lax.bitcast_convert_type(piece, x.dtype)
                    leaves[i] = jnp.reshape(value, x.shape)
        return jax.tree.unflatten(self.treedef, leaves)

    def report(self, bufs: tuple[jax.Array, ...]) -> tuple[Any, ...]:
        """``(obs, reward, terminated, truncated, info)`` read from a state's buffers."""
        if self.num_reported == 1:
            words = np.asarray(bufs[0])
        else:
            words = np.concatenate([np.asarray(b) for b in bufs[: self.num_reported]])
        scalars = words[self.scalars]
        reals = scalars.tolist()
        ints = scalars.view(np.int32).tolist()
        reward, terminated, truncated, *rest = reals
        info = {
            key: value if kind == "f" else (value != 0.0) if kind == "b" else _int(bits, kind)
            for (key, kind), value, bits in zip(self.info, rest, ints[3:], strict=True)
        }
        return words[self.obs].copy(), reward, terminated != 0.0, truncated != 0.0, info


Bufs = tuple[jax.Array, ...]


@dataclasses.dataclass(frozen=True)
class _Compiled:
    """Jitted functions of one (task, config, batch) shared by all facade instances.

    Vector env (``words is None``; ``bufs`` in :class:`_FlatState` form): ``reset(seed) ->
    (bufs, obs)``, ``step(bufs, action) -> (bufs, packed)``, ``reset_masked(bufs, seed,
    mask) -> (bufs, obs)``. Single env (``bufs`` in :class:`_Words` form, whose
    ``report`` reads a step's results from them): ``reset(seed) -> bufs`` and
    ``step(bufs, action) -> bufs``, which donates its ``bufs``. Both: ``unpack(bufs) ->
    State``.
    """

    env: Env
    batched: BatchedEnv | None
    layout: _Layout
    reset: Callable[[Any], Any]
    step: Callable[[Bufs, Any], Any]
    reset_masked: Callable[[Bufs, Any, Any], tuple[Bufs, jax.Array]] | None
    unpack: Callable[[Bufs], State]
    words: _Words | None = None


def _build(
    env_id: str,
    overrides: dict[str, Any],
    num_envs: int | None,
    randomize: bool,
    devices: int | None = None,
) -> _Compiled:
    env = registry.make(env_id, **overrides)
    assert isinstance(env, Env)
    layout = _Layout(env.observation_size, BASE_INFO_KEYS + tuple(env.metric_keys))
    if num_envs is None:
        return _build_single(env, layout)
    task = BatchedEnv(env, num_envs, randomize=randomize, devices=devices)
    seed0 = jax.ShapeDtypeStruct((), jnp.uint32)
    flat = _FlatState(jax.eval_shape(lambda s: task.reset(jax.random.key(s)), seed0), (num_envs,))

    def reset(seed: jax.Array) -> tuple[Bufs, jax.Array]:
        state = task.reset(jax.random.key(seed))
        return flat.pack(state), state.obs

    def step(bufs: Bufs, action: jax.Array) -> tuple[Bufs, jax.Array]:
        state = task.step(flat.unpack(bufs), action)
        return flat.pack(state), _pack(state, layout)

    def reset_masked(bufs: Bufs, seed: jax.Array, mask: jax.Array) -> tuple[Bufs, jax.Array]:
        fresh = task.reset(jax.random.key(seed))

        def pick(new: jax.Array, old: jax.Array) -> jax.Array:
            return jnp.where(mask.reshape(mask.shape + (1,) * (old.ndim - 1)), new, old)

        merged = jax.tree.map(pick, fresh, flat.unpack(bufs))
        return flat.pack(merged), merged.obs

    return _Compiled(
        env=env,
        batched=task,
        layout=layout,
        reset=jax.jit(reset),
        step=jax.jit(step),
        reset_masked=jax.jit(reset_masked),
        unpack=jax.jit(flat.unpack),
    )


def _build_single(env: Env, layout: _Layout) -> _Compiled:
    seed0 = jax.ShapeDtypeStruct((), jnp.uint32)
    words = _Words(jax.eval_shape(lambda s: env.reset(jax.random.key(s)), seed0), layout.info_keys)

    def reset(seed: jax.Array) -> Bufs:
        return words.pack(env.reset(jax.random.key(seed)))

    def step(bufs: Bufs, action: jax.Array) -> Bufs:
        return words.pack(env.step(words.unpack(bufs), action))

    return _Compiled(
        env=env,
        batched=None,
        layout=layout,
        reset=jax.jit(reset),
        step=jax.jit(step, donate_argnums=0),
        reset_masked=None,
        unpack=jax.jit(words.unpack),
        words=words,
    )


_CACHE: dict[Any, _Compiled] = {}


def compiled(
    env_id: str,
    overrides: dict[str, Any] | None = None,
    num_envs: int | None = None,
    randomize: bool = False,
    devices: int | None = None,
) -> _Compiled:
    """The shared jitted functions for ``env_id`` with ``overrides`` (built once)."""
    overrides = dict(overrides or {})
    config = registry.make_config(env_id, overrides, source=f"{gym_id(env_id)} kwargs")
    try:
        cache_key: Any = (registry.spec(env_id).factory, config, num_envs, randomize, devices)
        hash(cache_key)
    except TypeError:  # a config with unhashable fields: no sharing
        return _build(env_id, overrides, num_envs, randomize, devices)
    if cache_key not in _CACHE:
        _CACHE[cache_key] = _build(env_id, overrides, num_envs, randomize, devices)
    return _CACHE[cache_key]


# ------------------------------------------------------------------------- validation
def _space_text(env: Env, num_envs: int | None = None) -> str:
    space = env.action_space
    if num_envs is None:
        return str(space)
    return f"{num_envs} actions of {space}, shape {(num_envs, *env.action_shape)}"


def check_action(env: Env, action: Any, num_envs: int | None = None) -> np.ndarray:
    """Validate ``action`` on the host; returns it as a numpy array of the env's dtype.

    Raises ``ValueError`` naming the expected space for a wrong shape or dtype, or a
    discrete action out of range.
    """
    lead = () if num_envs is None else (num_envs,)
    expected = (*lead, *env.action_shape)

    def what() -> str:  # built only for an error: a space's text costs ~0.1 ms a step
        return _space_text(env, num_envs)

    if isinstance(action, (bool, np.bool_)):
        raise ValueError(f"expected an action in {what()}, got a bool")
    try:
        arr = np.asarray(action)
    except (TypeError, ValueError) as err:
        raise ValueError(f"expected an action in {what()}, got {type(action).__name__}") from err
    if arr.shape != expected:
        raise ValueError(
            f"expected an action in {what()} (shape {expected}), got shape {arr.shape}"
        )
    if env.discrete:
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"expected an integer action in {what()}, got dtype {arr.dtype}")
        if arr.size and (arr.min() < 0 or arr.max() >= env.action_size):
            raise ValueError(
                f"discrete action out of range for {what()}: valid actions are "
                f"0..{env.action_size - 1}, got {arr.min() if arr.min() < 0 else arr.max()}"
            )
        return arr.astype(np.int32, copy=False)
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"expected a floating-point action in {what()}, got dtype {arr.dtype}")
    return arr.astype(np.float32, copy=False)


def _display_available() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _check_render_mode(render_mode: str | None, human_ok: bool = False) -> None:
    if render_mode is None or render_mode in RENDER_MODES:
        return
    if render_mode == "human":
        if not _display_available():
            raise ValueError(
                "render_mode='human' needs a display and none was found (DISPLAY and "
                "WAYLAND_DISPLAY are unset); use render_mode='rgb_array' (frames, videos "
                "through gymnasium.wrappers.RecordVideo or `jaxenvs render`)"
            )
        if human_ok:  # the single env draws in MuJoCo's viewer (jaxenvs.render.viewer)
            return
        raise ValueError(
            "render_mode='human' has no native window in the Gymnasium facade yet; wrap an "
            "rgb_array env instead: gymnasium.wrappers.HumanRendering(gymnasium.make(id, "
            "render_mode='rgb_array'))"
        )
    raise ValueError(f"unsupported render_mode {render_mode!r}; supported: {RENDER_MODES}")


def _check_options(options: dict[str, Any] | None, allowed: tuple[str, ...]) -> dict[str, Any]:
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise TypeError(f"options must be a dict, got {type(options).__name__}")
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(
            f"unsupported reset options {unknown}; supported: {list(allowed) or 'none'}"
        )
    return options


def _seed32(rng: np.random.Generator) -> np.uint32:
    """A uint32 drawn from Gymnasium's ``np_random``: the seed of the next JAX key."""
    return rng.integers(0, 2**32, dtype=np.uint32)


def _render_fps(env: Env) -> int:
    return max(1, round(1.0 / env.control_dt))


# --------------------------------------------------------------------------- one env
class JaxEnv(gymnasium.Env):
    """One jaxenvs task as a standard ``gymnasium.Env`` (see the module docstring).

    Args:
      env_id: a registered jaxenvs id (without the ``jaxenvs/`` prefix).
      render_mode: ``None``, ``"rgb_array"``, or ``"human"``: MuJoCo's viewer window
        (:mod:`jaxenvs.render.viewer`), drawn in real time at every reset and step; needs a
        display (refused with a clear message where there is none).
      width, height, camera: frame size and camera for ``render()`` (see
        :mod:`jaxenvs.render`).
      **overrides: fields of the task's config.
    """

    metadata: dict[str, Any] = {"render_modes": _DECLARED_MODES, "render_fps": 50}

    def __init__(
        self,
        env_id: str,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | int | None = None,
        **overrides: Any,
    ) -> None:
        _check_render_mode(render_mode, human_ok=True)
        self._fns = compiled(env_id, overrides)
        self.env_id = env_id
        self.jax_env: Env = self._fns.env
        self.observation_space = self.jax_env.observation_space
        self.action_space = self.jax_env.action_space
        self.render_mode = render_mode
        # "human" is offered (and so exercised by Gymnasium's env checker) only where a
        # display exists; the class metadata always lists it so gymnasium.make passes it on.
        human = ["human"] if _display_available() else []
        self.metadata = {
            "render_modes": [*RENDER_MODES, *human],
            "render_fps": _render_fps(self.jax_env),
        }
        self._render_args = (width, height, camera)
        self._renderer: Any = None
        self._bufs: Bufs | None = None
        assert self._fns.words is not None
        self._words = self._fns.words
        #: the shape of a continuous action (checked at once when it comes as float32)
        self._float_shape = None if self.jax_env.discrete else self.jax_env.action_shape

    @property
    def state(self) -> State | None:
        """The current functional-API state (``None`` before the first reset)."""
        return None if self._bufs is None else self._fns.unpack(self._bufs)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        _check_options(options, ())
        self._bufs = self._fns.reset(_seed32(self.np_random))
        if self.render_mode == "human":
            self.render()
        return self._words.report(self._bufs)[0], {}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._bufs is None:
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        if type(action) is not np.ndarray or action.shape != self._float_shape:
            action = check_action(self.jax_env, action)  # else a float32 array of the shape
        elif action.dtype != np.float32:
            action = check_action(self.jax_env, action)
        self._bufs = self._fns.step(self._bufs, action)
        if self.render_mode == "human":
            self.render()
        obs, reward, terminated, truncated, info = self._words.report(self._bufs)
        return obs, reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() called without a render_mode; pass render_mode='rgb_array' to make()"
            )
            return None
        if self._bufs is None:
            raise ResetNeeded("Cannot call env.render() before calling env.reset()")
        if self.render_mode == "human":
            if self._renderer is None:
                from jaxenvs.render.viewer import StateViewer

                self._renderer = StateViewer(self.jax_env)
            self._renderer.show(self.state)
            return None
        if self._renderer is None:
            from jaxenvs.render import Renderer

            self._renderer = Renderer(self.jax_env, *self._render_args)
        return self._renderer.render_state(self.state)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()


# ------------------------------------------------------------------------ vector env
class JaxVectorEnv(VectorEnv):
    """``num_envs`` copies of a jaxenvs task as a ``gymnasium.vector.VectorEnv``.

    Args:
      env_id: a registered jaxenvs id (without the ``jaxenvs/`` prefix).
      num_envs: number of envs, stepped by one jitted vmapped function.
      max_episode_steps: the episode length (``make_vec`` passes the registered one);
        a different value overrides the task's ``episode_length``.
      randomize: draw per-env params at every reset (domain randomisation).
      devices: local devices the batch is spread over (default: all that ``num_envs``
        divides over; ``1``: none), as :func:`jaxenvs.make`.
      render_mode: ``None`` or ``"rgb_array"`` (``render()`` returns one frame per env).
      width, height, camera: frame size and camera.
      **overrides: fields of the task's config.
    """

    metadata: dict[str, Any] = {
        "autoreset_mode": AutoresetMode.SAME_STEP,
        "render_modes": _DECLARED_MODES,
        "render_fps": 50,
    }

    def __init__(
        self,
        env_id: str,
        num_envs: int = 1,
        max_episode_steps: int | None = None,
        randomize: bool = False,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | int | None = None,
        devices: int | None = None,
        **overrides: Any,
    ) -> None:
        _check_render_mode(render_mode)
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        if max_episode_steps is not None:
            default = registry.make_config(env_id, overrides).episode_length
            if int(max_episode_steps) != default:
                overrides["episode_length"] = int(max_episode_steps)
        self._fns = compiled(env_id, overrides, num_envs, bool(randomize), devices)
        self.env_id = env_id
        self.jax_env: Env = self._fns.env
        self.num_envs = num_envs
        self.single_observation_space = self.jax_env.observation_space
        self.single_action_space = self.jax_env.action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.render_mode = render_mode
        self.metadata = {
            "autoreset_mode": AutoresetMode.SAME_STEP,
            "render_modes": RENDER_MODES,
            "render_fps": _render_fps(self.jax_env),
        }
        self._render_args = (width, height, camera)
        self._renderer: Any = None
        self._bufs: Bufs | None = None
        self._n = self.jax_env.observation_size
        self._info_keys = self._fns.layout.info_keys
        self._all = np.ones(num_envs, dtype=bool)

    @property
    def state(self) -> State | None:
        """The current batched functional-API state (``None`` before the first reset)."""
        return None if self._bufs is None else self._fns.unpack(self._bufs)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise ValueError(f"seed must be an int or None, got {type(seed).__name__}")
        super().reset(seed=seed)
        opts = _check_options(options, ("reset_mask",))
        seed32 = _seed32(self.np_random)
        if "reset_mask" not in opts:
            self._bufs, obs = self._fns.reset(seed32)
            return np.array(obs), {}
        mask = opts["reset_mask"]
        if not isinstance(mask, np.ndarray):
            raise TypeError(f"options['reset_mask'] must be a numpy array, got {type(mask)}")
        if mask.shape != (self.num_envs,) or mask.dtype != np.bool_:
            raise ValueError(
                f"options['reset_mask'] must be a bool array of shape ({self.num_envs},), "
                f"got {mask.dtype} {mask.shape}"
            )
        if not mask.any():
            raise ValueError("options['reset_mask'] must contain at least one True value")
        if self._bufs is None:
            raise ResetNeeded("reset with a reset_mask needs a full reset() first")
        assert self._fns.reset_masked is not None
        self._bufs, obs = self._fns.reset_masked(self._bufs, seed32, mask)
        return np.array(obs), {}

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if self._bufs is None:
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        actions = check_action(self.jax_env, actions, self.num_envs)
        self._bufs, packed = self._fns.step(self._bufs, actions)
        buf = np.asarray(packed)
        n, r = self._n, 2 * self._n
        obs = np.ascontiguousarray(buf[:, :n])
        rewards = buf[:, r].astype(np.float64)
        terminated = buf[:, r + 1] > 0.5
        truncated = buf[:, r + 2] > 0.5
        done = terminated | truncated
        values = {
            k: (buf[:, r + 3 + j] > 0.5) if k == "diverged" else buf[:, r + 3 + j].copy()
            for j, k in enumerate(self._info_keys)
        }
        values["nan_actions"] = values["nan_actions"].astype(np.int64)
        infos: dict[str, Any] = {}
        if not done.any():
            for k, v in values.items():
                infos[k], infos[f"_{k}"] = v, self._all
            return obs, rewards, terminated, truncated, infos
        # SAME_STEP: finished envs report their last step under final_obs / final_info;
        # the top-level info of an auto-reset env is its (empty) reset info.
        running = ~done
        if running.any():  # as SyncVectorEnv: a key exists only if some env reports it
            for k, v in values.items():
                infos[k], infos[f"_{k}"] = v, running
        final_obs = np.full(self.num_envs, None, dtype=object)
        for i in np.flatnonzero(done):
            final_obs[i] = buf[i, n:r].copy()
        final_info: dict[str, Any] = {}
        for k, v in values.items():
            final_info[k], final_info[f"_{k}"] = v, done
        infos["final_obs"], infos["_final_obs"] = final_obs, done
        infos["final_info"], infos["_final_info"] = final_info, done
        return obs, rewards, terminated, truncated, infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() called without a render_mode; pass render_mode='rgb_array'"
            )
            return None
        if self._bufs is None:
            raise ResetNeeded("Cannot call render() before calling reset()")
        if self._renderer is None:
            from jaxenvs.render import Renderer

            self._renderer = Renderer(self.jax_env, *self._render_args)
        state = self.state
        assert state is not None
        data = state.data
        qpos, mpos, mquat = (np.asarray(x) for x in (data.qpos, data.mocap_pos, data.mocap_quat))
        return tuple(self._renderer.frame(qpos[i], mpos[i], mquat[i]) for i in range(self.num_envs))

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


registry.add_listener(register_spec)
