"""A test script in a fresh process with a forced number of XLA CPU host devices.

The CPU's device count is fixed when JAX starts, so a test of several host devices runs
its checks in a subprocess started with ``XLA_FLAGS=--xla_force_host_platform_device_count``
(and without ``JAX_NUM_CPU_DEVICES``, which would override it).
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Mapping, Sequence


def run_with_devices(
    count: int, script: str, args: Sequence[str] = (), env: Mapping[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """``python -c script *args`` on ``count`` host devices (``env``: more variables);
    asserts that it exited 0, with the end of its stderr as the message."""
    environ = {**os.environ, **(env or {})}
    environ["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={count}"
    environ.pop("JAX_NUM_CPU_DEVICES", None)
    proc = subprocess.run(
        [sys.executable, "-c", script, *args],
        env=environ,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc
