"""Typed, frozen configs: overrides, validation and safe YAML loading.

Every task and agent has a frozen dataclass config. ``apply_overrides`` is the one
place where user input (keyword overrides, YAML sections, command-line flags) meets a
config: unknown keys, wrong types and impossible values raise :class:`ConfigError`
naming the key and where it came from.

Rules every config obeys, whatever its own ``validate`` adds: an integer setting fits in
32 bits (what a compiled program computes with: a seed or a size beyond that would fail
or wrap inside JAX), and a float setting is finite (no NaN, no infinity: a bound or rate
of ``inf`` turns a check off silently, a NaN poisons every number it touches).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml

C = TypeVar("C")

#: the range of an integer setting (int32)
INT_MIN, INT_MAX = -(2**31), 2**31 - 1

#: the largest config file read (bytes); checked before parsing
MAX_CONFIG_BYTES = 2**20

#: unknown keys an error message names before it says how many more there are
SHOWN_KEYS = 5


class ConfigError(ValueError):
    """A config value is unknown, of the wrong type or impossible."""


def _short(value: Any) -> str:
    """``repr(value)`` cut to 60 characters, for one-line error messages."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _plain(value: Any) -> Any:
    """A numpy scalar as the Python scalar it holds (a numpy bool stays a bool, so it is
    no more an integer than Python's); anything else as it is."""
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def _coerce(name: str, value: Any, hint: Any, source: str) -> Any:
    """Check ``value`` against the type ``hint`` and convert lists to tuples (and numpy
    scalars to Python's)."""
    value = _plain(value)
    origin = typing.get_origin(hint)
    if origin is typing.Union or origin is types.UnionType:
        errors = []
        for arg in typing.get_args(hint):
            if arg is type(None):
                if value is None:
                    return None
                continue
            try:
                return _coerce(name, value, arg, source)
            except ConfigError as err:
                errors.append(str(err))
        if len(errors) == 1:  # ``X | None``: X's own message says what is wrong
            raise ConfigError(errors[0])
        raise ConfigError(f"{source}: key {name!r} expects {hint}, got {_short(value)}")
    if origin is typing.Literal:
        if value not in typing.get_args(hint):
            raise ConfigError(
                f"{source}: key {name!r} must be one of {typing.get_args(hint)}, "
                f"got {_short(value)}"
            )
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{source}: key {name!r} expects a list, got {_short(value)}")
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(name, v, args[0], source) for v in value)
        if len(args) != len(value):
            raise ConfigError(
                f"{source}: key {name!r} expects {len(args)} values, got {len(value)}"
            )
        return tuple(_coerce(name, v, a, source) for v, a in zip(value, args, strict=True))
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: key {name!r} expects true/false, got {_short(value)}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{source}: key {name!r} expects an integer, got {_short(value)}")
        if not INT_MIN <= value <= INT_MAX:
            raise ConfigError(
                f"{source}: key {name!r} must fit in 32 bits ({INT_MIN}..{INT_MAX}), got {value}"
            )
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{source}: key {name!r} expects a number, got {_short(value)}")
        try:
            number = float(value)
        except OverflowError:  # an int too large for a float
            number = math.inf
        if not math.isfinite(number):
            raise ConfigError(
                f"{source}: key {name!r} must be a finite number, got {_short(value)}"
            )
        return number
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{source}: key {name!r} expects a string, got {_short(value)}")
        return value
    return value


def apply_overrides(config: C, overrides: Mapping[str, Any], source: str) -> C:
    """Return ``config`` with ``overrides`` applied, validated and type-checked.

    Args:
      config: a frozen dataclass instance.
      overrides: field name -> new value.
      source: where the overrides came from (a file path, "command line", ...), used in
        error messages.

    Raises:
      ConfigError: for an unknown key (the message lists the valid ones), a value of the
        wrong type, or a value the config's ``validate`` rejects.
    """
    if not dataclasses.is_dataclass(config) or isinstance(config, type):
        raise TypeError(f"expected a dataclass instance, got {type(config)!r}")
    fields = {f.name: f for f in dataclasses.fields(config)}
    hints = typing.get_type_hints(type(config))
    unknown = sorted(set(overrides) - set(fields), key=str)
    if unknown:
        raise ConfigError(
            f"{source}: unknown key(s) {name_some(unknown)} for "
            f"{type(config).__name__}; valid keys: {', '.join(sorted(fields))}"
        )
    coerced = {k: _coerce(k, v, hints[k], source) for k, v in overrides.items()}
    new = dataclasses.replace(config, **coerced)  # type: ignore[type-var]
    validate = getattr(new, "validate", None)
    if validate is not None:
        try:
            validate()
        except ConfigError as err:
            raise ConfigError(f"{source}: {err}") from None
    return new


def name_some(keys: list[Any]) -> str:
    """``keys`` as an error message lists them: the first :data:`SHOWN_KEYS`, each cut to
    128 characters, then how many more there are."""
    shown = [repr(k) if len(repr(k)) <= 128 else repr(k)[:125] + "..." for k in keys[:SHOWN_KEYS]]
    more = len(keys) - len(shown)
    return ", ".join(shown) + (f" and {more} more" if more else "")


def require(condition: bool, key: str, message: str) -> None:
    """Raise :class:`ConfigError` naming ``key`` unless ``condition`` holds."""
    if not condition:
        raise ConfigError(f"key {key!r} {message}")


def config_to_dict(config: Any) -> dict[str, Any]:
    """A YAML-friendly dict of a dataclass config (tuples become lists)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            value = config_to_dict(value)
        elif isinstance(value, tuple):
            value = list(value)
        out[f.name] = value
    return out


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Load a YAML mapping with the safe loader; errors name the file.

    Python-object tags (``!!python/object``) are rejected by the safe loader and never
    executed. A file over :data:`MAX_CONFIG_BYTES` is refused before it is parsed, and
    one that is not UTF-8 text is refused naming it.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    size = path.stat().st_size
    if size > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{path}: {size} bytes is too large for a config file (the limit is "
            f"{MAX_CONFIG_BYTES} bytes)"
        )
    try:
        text = path.read_bytes()[: MAX_CONFIG_BYTES + 1].decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(
            f"{path}: not UTF-8 text (byte {err.start}: {err.reason}); save it as UTF-8"
        ) from None
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's, when built with it
    try:
        data = yaml.load(text, Loader=loader)  # noqa: S506 - a safe loader
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML ({_first_line(err)})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    return data


def _first_line(err: Exception) -> str:
    """The first line of an error's text, at most 200 characters."""
    line = (str(err).strip().splitlines() or [type(err).__name__])[0]
    return line if len(line) <= 200 else line[:197] + "..."
