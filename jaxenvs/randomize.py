"""Sampling helpers for domain randomisation, shared by every robot's ``sample_fields``
(:mod:`jaxenvs.robots.base`) and every task's ``sample_params``.

A task's params pytree carries the physical quantities worth randomising (MJX model
fields such as ``body_mass`` or ``actuator_gear``, which its robot names and draws, plus
task quantities such as a target range). Its config holds one *range* per randomised
quantity, a ``(low, high)`` pair (the robot's ranges come from the robot's
``Randomization`` config, which the task config inherits):

* a **scale range** multiplies the default value by a factor drawn uniformly in
  ``[low, high]`` (``(1.0, 1.0)`` switches that quantity's randomisation off);
* an **offset range** adds a value drawn uniformly in ``[low, high]`` (for quantities
  whose default is 0, such as a frictionless joint's damping);
* a **value range** replaces the quantity by a value drawn uniformly in ``[low, high]``.

Every helper is a pure function of an explicit key; factors are drawn independently per
element (per body, per dof, per actuator) unless an index mask restricts them. A sampler
that draws several quantities should draw them with :func:`uniforms` (one PRNG call for
all of them) and apply them with :func:`scaled` or :func:`shifted`: on a CPU each PRNG
call is a loop that XLA compiles on its own, so a randomised reset's compile time and
memory grow with the number of calls, not with the number of values drawn. Configs
validate their ranges with :func:`check_range` so that a bad range fails at ``make``
time with the key's name, not as NaNs later.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp

from jaxenvs.config import require

Range = tuple[float, float]


def check_range(
    name: str,
    value: Range,
    *,
    min_low: float | None = None,
    max_high: float | None = None,
    positive: bool = False,
) -> None:
    """Validate a ``(low, high)`` range; raises :class:`jaxenvs.config.ConfigError`.

    Args:
      name: the config key, used in the message.
      value: the range.
      min_low: ``low`` must be >= this.
      max_high: ``high`` must be <= this.
      positive: ``low`` must be > 0 (scale ranges: a zero mass or gain is not physics).
    """
    require(len(value) == 2, name, f"must be a (low, high) pair, got {value!r}")
    low, high = float(value[0]), float(value[1])
    require(low <= high, name, f"needs low <= high, got {value!r}")
    if positive:
        require(low > 0, name, f"needs low > 0, got {value!r}")
    if min_low is not None:
        require(low >= min_low, name, f"needs low >= {min_low}, got {value!r}")
    if max_high is not None:
        require(high <= max_high, name, f"needs high <= {max_high}, got {value!r}")


def _in_range(u: jax.Array, value_range: Range) -> jax.Array:
    """Uniforms ``u`` in [0, 1) mapped onto ``[low, high]`` (exactly ``low`` if equal)."""
    low, high = value_range
    return jnp.float32(low) + u * jnp.float32(high - low)


def uniform(key: jax.Array, value_range: Range, shape: tuple[int, ...] = ()) -> jax.Array:
    """Float32 values drawn uniformly in ``[low, high]`` (exactly ``low`` if equal)."""
    return _in_range(jax.random.uniform(key, shape, jnp.float32), value_range)


def uniforms(key: jax.Array, draws: Sequence[tuple[Range, tuple[int, ...]]]) -> list[jax.Array]:
    """Several float32 draws, each uniform in its ``(low, high)`` range and of its shape,
    from ONE PRNG call: draw ``i`` is the next ``prod(shape_i)`` values of one uniform
    vector, so each keeps the distribution of :func:`uniform` (independent elements), and
    a draw does not depend on the draws listed after it."""
    sizes = [math.prod(shape) for _, shape in draws]
    u = jax.random.uniform(key, (sum(sizes),), jnp.float32)
    out, start = [], 0
    for (value_range, shape), size in zip(draws, sizes, strict=True):
        out.append(_in_range(u[start : start + size].reshape(shape), value_range))
        start += size
    return out


def scaled(value: jax.Array, factor: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    """``value`` times ``factor`` (one per leading index: shape ``value.shape[:1]``, or
    ``value.shape``), in ``value``'s dtype; rows outside ``mask`` keep their value."""
    value = jnp.asarray(value)
    factor = factor.reshape(factor.shape + (1,) * (value.ndim - factor.ndim))
    return _masked((value * factor).astype(value.dtype), value, mask)


def shifted(value: jax.Array, delta: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    """``value`` plus ``delta`` (of ``value``'s shape), in ``value``'s dtype; rows outside
    ``mask`` keep their value."""
    value = jnp.asarray(value)
    return _masked((value + delta).astype(value.dtype), value, mask)


def _masked(new: jax.Array, old: jax.Array, mask: jax.Array | None) -> jax.Array:
    if mask is None:
        return new
    mask = jnp.asarray(mask, bool)
    return jnp.where(mask.reshape(mask.shape + (1,) * (old.ndim - mask.ndim)), new, old)


def scale(
    key: jax.Array, value: jax.Array, scale_range: Range, mask: jax.Array | None = None
) -> jax.Array:
    """``value`` times a factor uniform in ``scale_range``, one factor per leading index.

    ``mask`` (bool, shape ``value.shape[:1]``) limits the change to selected rows (e.g.
    the arm's bodies, not the world body); unselected rows keep their value.
    """
    value = jnp.asarray(value)
    return scaled(value, uniform(key, scale_range, value.shape[:1]), mask)


def offset(
    key: jax.Array, value: jax.Array, offset_range: Range, mask: jax.Array | None = None
) -> jax.Array:
    """``value`` plus an amount uniform in ``offset_range``, drawn per element."""
    value = jnp.asarray(value)
    return shifted(value, uniform(key, offset_range, value.shape), mask)


def scale_mass(
    key: jax.Array,
    body_mass: jax.Array,
    body_inertia: jax.Array,
    scale_range: Range,
    mask: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Scale each body's mass and its inertia by the SAME factor (a density change).

    Scaling the mass alone would give a body whose inertia no longer matches its shape.
    """
    factor = uniform(key, scale_range, body_mass.shape)
    return scaled(body_mass, factor, mask), scaled(body_inertia, factor, mask)


def scale_fields(
    key: jax.Array,
    fields: Mapping[str, jax.Array],
    ranges: Mapping[str, Range],
    masks: Mapping[str, jax.Array] | None = None,
) -> dict[str, jax.Array]:
    """Apply :func:`scale` to each named model field with its own range and subkey.

    Fields without a range are returned unchanged. Each field's subkey is ``key`` folded
    with a checksum of the field's name, so the draw of one field does not depend on
    which other fields are randomised (JAX's default partitionable threefry: a draw's
    first ``n`` values do not depend on its length). All fields are drawn in two PRNG
    calls (the subkeys, then their factors), whatever their number.
    """
    masks = masks or {}
    missing = sorted(n for n in ranges if n not in fields)
    if missing:
        raise KeyError(f"no model field(s) {missing} to randomise; have {sorted(fields)}")
    out = dict(fields)
    if not ranges:
        return out
    names = list(ranges)
    salts = jnp.asarray([zlib.crc32(n.encode()) & 0x7FFFFFFF for n in names], jnp.uint32)
    subs = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, salts)
    longest = max(jnp.shape(fields[n])[0] if jnp.ndim(fields[n]) else 1 for n in names)
    draws = jax.vmap(lambda k: jax.random.uniform(k, (longest,), jnp.float32))(subs)
    for i, name in enumerate(names):
        value = jnp.asarray(fields[name])
        u = draws[i, : value.shape[0] if value.ndim else 1].reshape(value.shape[:1])
        out[name] = scaled(value, _in_range(u, ranges[name]), masks.get(name))
    return out
