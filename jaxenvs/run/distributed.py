"""One run over several hosts, on JAX's own distributed runtime.

Start the same command once per host (one process a host), each told where process 0
listens, how many processes there are and which one it is, by flags or by variables::

    # on host 0; on host 1 the same with --process-id 1
    jaxenvs train HexapodWalk-v0 --algo ppo --coordinator host0:1234 \\
        --num-processes 2 --process-id 0 --out runs/walk

(or ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID``; under SLURM's
``srun`` or Open MPI's ``mpirun`` none of them: JAX reads the launcher's own).
:func:`initialize` calls :func:`jax.distributed.initialize` before the command's first
JAX operation; from then on :func:`jax.devices` lists every host's devices and the run's
mesh spans them all (:mod:`jaxenvs.run.placement`): each host steps the envs of its own
devices, and only the collectives of the program per device cross hosts. Every process
computes the same results; each writes them to its own run directory
(:func:`process_out_dir`), the checkpoint gathered from every host.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax

from jaxenvs.core.sharding import DISTRIBUTED_ENV_VARS, distributed_args


@dataclasses.dataclass(frozen=True)
class Cluster:
    """Where this process stands in a run over several processes: process 0's
    ``host:port``, the number of processes and this one's index."""

    coordinator: str
    num_processes: int
    process_id: int

    def validate(self) -> None:
        """Raise ``ValueError`` naming the value that cannot describe a cluster."""
        host, _, port = self.coordinator.rpartition(":")
        if not host or not port.isdigit():
            raise ValueError(f"--coordinator must be host:port, got {self.coordinator!r}")
        if self.num_processes < 1:
            raise ValueError(f"--num-processes must be >= 1, got {self.num_processes}")
        if not 0 <= self.process_id < self.num_processes:
            raise ValueError(
                f"--process-id must lie in 0..{self.num_processes - 1}, got {self.process_id}"
            )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags of a run over several hosts (each defaults to JAX's variable)."""
    group = parser.add_argument_group("several hosts (docs/devices.md)")
    group.add_argument(
        "--coordinator", metavar="HOST:PORT", help="process 0's address (JAX_COORDINATOR_ADDRESS)"
    )
    group.add_argument(
        "--num-processes", type=int, help="processes, one a host (JAX_NUM_PROCESSES)"
    )
    group.add_argument("--process-id", type=int, help="this process's index (JAX_PROCESS_ID)")


def cluster(
    coordinator: str | None,
    num_processes: int | None,
    process_id: int | None,
    environ: Mapping[str, str] | None = None,
) -> Cluster | dict[str, Any] | None:
    """The cluster the flags (over the environment's variables) describe: ``None`` for a
    single process, ``{}`` for a launcher JAX reads itself (SLURM, Open MPI), else a
    validated :class:`Cluster`. Raises ``ValueError`` naming what is missing when only
    some of the three are given."""
    env = dict(os.environ if environ is None else environ)
    given = (coordinator, num_processes, process_id)
    for value, var in zip(given, DISTRIBUTED_ENV_VARS, strict=True):
        if value is not None:
            env[var] = str(value)
    try:
        args = distributed_args(env)
    except ValueError as err:
        flags = "--coordinator, --num-processes and --process-id"
        raise ValueError(f"{err}; on the command line: {flags}") from None
    if not args:
        return args
    found = Cluster(args["coordinator_address"], args["num_processes"], args["process_id"])
    found.validate()
    return found


def initialize(found: Cluster | dict[str, Any] | None) -> bool:
    """Join the cluster ``found`` (:func:`cluster`) through
    :func:`jax.distributed.initialize`; call it before the first JAX operation. Returns
    whether this process is part of a run over several processes. Safe to call twice."""
    if found is None:
        return False
    if not jax.distributed.is_initialized():
        if isinstance(found, Cluster):
            jax.distributed.initialize(
                coordinator_address=found.coordinator,
                num_processes=found.num_processes,
                process_id=found.process_id,
            )
        else:
            jax.distributed.initialize()
    return True


def initialize_from(args: argparse.Namespace) -> bool:
    """:func:`initialize` with the flags of :func:`add_arguments` (and the environment)."""
    return initialize(cluster(args.coordinator, args.num_processes, args.process_id))


def process_out_dir(out: Path) -> Path:
    """The run directory this process writes: ``out`` for process 0 (and a single
    process), ``out`` with ``.process<k>`` appended for process ``k``, so that processes
    sharing a filesystem never write one directory."""
    k = jax.process_index() if jax.distributed.is_initialized() else 0
    return out if k == 0 else out.with_name(f"{out.name}.process{k}")
