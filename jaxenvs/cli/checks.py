"""Range checks of numeric command-line flags that do not go through a config.

Flags that set a config field (``--seed``, ``--num-envs``, ...) are checked by
:func:`jaxenvs.config.apply_overrides`; the others use these, so that an absurd value is
one line naming the flag (:class:`~jaxenvs.config.ConfigError`), not a traceback from
deep inside JAX.
"""

from __future__ import annotations

import math

from jaxenvs.config import INT_MAX, ConfigError


def int_flag(flag: str, value: int | None, low: int, high: int = INT_MAX) -> None:
    """Raise :class:`ConfigError` naming ``flag`` unless ``value`` is ``None`` or in
    ``[low, high]``."""
    if value is not None and not low <= value <= high:
        raise ConfigError(f"{flag} must be between {low} and {high}, got {value}")


def float_flag(flag: str, value: float | None, low: float, high: float) -> None:
    """Raise :class:`ConfigError` naming ``flag`` unless ``value`` is ``None`` or a finite
    number in ``[low, high]``."""
    if value is not None and not (math.isfinite(value) and low <= value <= high):
        raise ConfigError(f"{flag} must be a finite number between {low} and {high}, got {value}")
