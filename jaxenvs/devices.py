"""Device counting and validation for batches of envs: one place for the rules and errors.

A batch of ``num_envs`` envs is spread over ``n`` devices by splitting its leading (env)
axis over a 1-D mesh whose axis is :data:`ENV_AXIS`; ``num_envs`` must then be a
multiple of ``n``. :func:`batch_devices` picks ``n`` for a :class:`jaxenvs.core.BatchedEnv`
(this process's local devices); :mod:`jaxenvs.sharding` uses :func:`check_count` and
:func:`check_divisible` for meshes over every host's devices. Every error is a
``ValueError`` that names the numbers involved and a valid alternative.
"""

from __future__ import annotations

import warnings

import jax

#: name of the mesh axis an env batch is split over (see :mod:`jaxenvs.sharding`).
ENV_AXIS = "envs"


def divisible_devices(num_envs: int, available: int) -> int:
    """The most devices, at most ``available``, that ``num_envs`` splits over evenly."""
    return max(d for d in range(1, min(available, num_envs) + 1) if num_envs % d == 0)


def check_count(devices: object, available: int, platform: str, local: bool = False) -> int:
    """``devices`` as an int, after checking it is a positive integer at most ``available``.

    Raises ``ValueError`` otherwise; the message says how to get more devices on a CPU
    (``local=True`` also names :func:`jaxenvs.machine.use_cores`).
    """
    if isinstance(devices, bool) or not isinstance(devices, int) or devices < 1:
        raise ValueError(f"devices must be a positive integer, got {devices!r}")
    if devices > available:
        knob = "call jaxenvs.machine.use_cores first, or " if local else ""
        raise ValueError(
            f"asked for {devices} devices but only {available} are available "
            f"({platform}); on a CPU {knob}set "
            f"XLA_FLAGS=--xla_force_host_platform_device_count={devices} before JAX starts"
        )
    return devices


def check_divisible(num_envs: int, devices: int, hint: str = "") -> None:
    """Raise ``ValueError`` unless ``num_envs`` splits evenly over ``devices``.

    The message names the nearest multiples of ``devices``; ``hint`` is appended to its
    "or fewer devices" (e.g. the command-line option that sets the count).
    """
    if num_envs % devices:
        lower = max(devices, num_envs - num_envs % devices)
        raise ValueError(
            f"num_envs={num_envs} does not divide evenly over {devices} devices: use a "
            f"multiple of {devices} (e.g. {lower} or {lower + devices}), or fewer devices"
            f"{hint}"
        )


def batch_devices(num_envs: int, devices: int | None, physics: str) -> int:
    """How many local devices a batch of ``num_envs`` envs is spread over.

    ``devices=None`` (the default) means all local devices of JAX's default backend (CPU
    host devices, see :mod:`jaxenvs.machine`, or GPUs), or as many of them as
    ``num_envs`` divides over evenly, with a warning when that is fewer; under the C
    engine one (its own threads spread the batch). An explicit count must divide
    ``num_envs`` and exist, or ``ValueError`` names the nearest valid sizes.
    """
    available = jax.local_device_count()
    if devices is None:
        if physics == "c" or available == 1:
            return 1
        n = divisible_devices(num_envs, available)
        if n < available and num_envs >= available:
            lower = num_envs - num_envs % available
            warnings.warn(
                f"num_envs={num_envs} does not divide over the {available} local devices: "
                f"spreading over {n} (a multiple of {available}, e.g. {lower} or "
                f"{lower + available}, uses them all)",
                stacklevel=3,
            )
        return n
    check_count(devices, available, jax.default_backend(), local=True)
    check_divisible(num_envs, devices)
    return devices
