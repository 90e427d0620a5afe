"""Result files: one JSON schema for every figure in benchmarks/RESULTS.md.

A result file is ``benchmarks/results/NAME.json``, named by what it measures, holding one
run of one command on one machine:

.. code-block:: text

    {
      "schema": 1,
      "name": "engines_cpu2_walker",          # == the file's stem
      "title": "HexapodWalk-v0 under MJX and C beside the peers, 2 cores",
      "machine": {                             # where it ran
        "description": "the shared 2-core development machine",
        "cpu": "x86_64", "cores": 2,           # cores: os.cpu_count() (or affinity)
        "gpu": null,                           # or "NVIDIA H200", "2 x NVIDIA H200"
        ...                                    # free: host, backend, device_count, load
      },
      "commit": "3094ab0",                     # git rev-parse --short HEAD (+ "-dirty")
      "versions": {"python": "3.11.7", "jax": "0.10.2", "mujoco": "4.0.0", ...},
      "command": "jaxenvs bench --tasks ...",  # what to type to measure it again
      "date": "2026-11-24T15:02:11Z",          # UTC, when it was measured
      "engine": "mjx",                         # optional: the physics of rows without their own
      "recovered": {"commit": "..."},          # optional: fields recovered after the fact
      "notes": "...",                          # optional: what a reader must know
      "rows": [{...}, ...],                    # the figures, one flat record each
      "extra": {...}                           # optional: anything else the tool wrote
    }

``rows`` are flat records (numbers, strings, booleans, null, lists of those). Rows of
``jaxenvs bench`` carry ``physics`` (the engine of that row). Files measured before this
schema were converted once (benchmarks/NOTES.md); what they lacked (machine,
commit, versions, date) was recovered from git history and the notes of the time, and each
such field is listed in ``recovered`` with its source and marked in its value, e.g.
``"commit": "290f6ff (recovered: the commit that added the file)"``.

Tools write files with :func:`write`, which fills in machine, commit, versions and date.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import json
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

SCHEMA = 1
RESULTS_DIR = Path(__file__).resolve().parent / "results"
#: the help of the tools' --json option
HELP = "write the result file here (a bare NAME: benchmarks/results/NAME.json)"
REQUIRED = {
    "schema": int,
    "name": str,
    "title": str,
    "machine": dict,
    "commit": str,
    "versions": dict,
    "command": str,
    "date": str,
    "rows": list,
}
MACHINE_REQUIRED = ("cpu", "cores", "gpu")
#: distributions whose versions a result file records, where installed
PACKAGES = (
    "jax",
    "jaxlib",
    "mujoco",
    "mujoco-mjx",
    "flax",
    "optax",
    "numpy",
    "gymnasium",
    "envpool",
    "gymnax",
    "stable-baselines3",
    "torch",
    "brax",
    "jaxenvs",
)


class ResultFileError(ValueError):
    """A result file that does not follow the schema; the message names the file."""


def versions() -> dict[str, str]:
    """Python's and every installed package of :data:`PACKAGES`' version."""
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return out


def commit() -> str:
    """The checkout's short commit, with ``-dirty`` when tracked files differ from it."""
    root = Path(__file__).resolve().parent.parent

    def git(*args: str) -> str:
        done = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, check=True)
        return done.stdout.strip()

    try:
        head = git("rev-parse", "--short", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return head + ("-dirty" if dirty else "")


def machine(description: str = "") -> dict[str, Any]:
    """CPU, usable cores and GPU of this machine (the GPU as JAX sees it, if JAX is loaded)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 0
    info: dict[str, Any] = {
        "description": description,
        "host": platform.node(),
        "cpu": _cpu_model(),
        "cores": cores,
        "gpu": None,
    }
    if "jax" in sys.modules:  # a tool that measured with JAX has it loaded already
        import jax

        devs = jax.devices()
        info["backend"] = jax.default_backend()
        info["device_count"] = len(devs)
        if jax.default_backend() == "gpu":
            kind = devs[0].device_kind
            info["gpu"] = kind if len(devs) == 1 else f"{len(devs)} x {kind}"
    return info


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def record(
    name: str,
    title: str,
    rows: list[dict[str, Any]],
    *,
    description: str = "",
    engine: str | None = None,
    notes: str = "",
    extra: dict[str, Any] | None = None,
    argv: list[str] | None = None,
) -> dict[str, Any]:
    """A result record for ``rows`` measured now, by this command, on this machine."""
    args = sys.argv if argv is None else argv
    out: dict[str, Any] = {
        "schema": SCHEMA,
        "name": name,
        "title": title,
        "machine": machine(description),
        "commit": commit(),
        "versions": versions(),
        "command": " ".join(args if args and not args[0].endswith(".py") else ["python", *args]),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }
    if engine is not None:
        out["engine"] = engine
    if notes:
        out["notes"] = notes
    out["rows"] = rows
    if extra:
        out["extra"] = extra
    return out


def write(path: str | Path, rec: dict[str, Any]) -> Path:
    """Check ``rec`` against the schema and write it; a bare name goes to results/NAME.json."""
    p = Path(path)
    if p.parent == Path(".") and p.suffix == "":
        p = RESULTS_DIR / f"{p}.json"
    rec = dict(rec, name=p.stem)
    validate(rec, str(p))
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(rec, indent=1, default=_jsonable) + "\n")
    print(f"# wrote {p}", flush=True)
    return p


def write_plan_run(
    path: str,
    title: str,
    script: str,
    plan: str,
    rows: list[dict[str, Any]],
    description: str = "",
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``rows`` that ``benchmarks/SCRIPT 'PLAN'`` measured in this process on the
    CPU; the recorded command carries the ``XLA_FLAGS`` it ran under (its host devices)."""
    flags = os.environ.get("XLA_FLAGS", "")
    command = ["JAX_PLATFORMS=cpu", *([f"XLA_FLAGS={flags}"] if flags else [])]
    command += ["python", f"benchmarks/{script}", f"'{plan}'"]
    name = os.path.basename(path)
    rec = record(name, title, rows, description=description, extra=extra, argv=command)
    return write(path, rec)


def _jsonable(x: Any) -> Any:
    if hasattr(x, "tolist"):  # numpy scalars and arrays
        return x.tolist()
    return str(x)


def validate(rec: Any, where: str) -> dict[str, Any]:
    """``rec`` itself if it follows the schema; else :class:`ResultFileError` naming ``where``."""
    if not isinstance(rec, dict):
        raise ResultFileError(f"{where}: not a JSON object")
    for key, typ in REQUIRED.items():
        if key not in rec:
            raise ResultFileError(f"{where}: missing field {key!r}")
        if not isinstance(rec[key], typ):
            raise ResultFileError(f"{where}: field {key!r} is not a {typ.__name__}")
    if rec["schema"] != SCHEMA:
        raise ResultFileError(f"{where}: schema {rec['schema']}, expected {SCHEMA}")
    if rec["name"] != Path(where).stem:
        raise ResultFileError(f"{where}: name {rec['name']!r} differs from the file name")
    for key in MACHINE_REQUIRED:
        if key not in rec["machine"]:
            raise ResultFileError(f"{where}: machine has no {key!r}")
    if not rec["rows"] or not all(isinstance(r, dict) for r in rec["rows"]):
        raise ResultFileError(f"{where}: rows must be a non-empty list of objects")
    return rec


def load(path: str | Path) -> dict[str, Any]:
    """Read and check one result file; every failure is one line naming the file."""
    p = Path(path)
    try:
        rec = json.loads(p.read_text())
    except OSError as e:
        raise ResultFileError(f"{p}: cannot read: {e.strerror}") from None
    except json.JSONDecodeError as e:
        raise ResultFileError(f"{p}: not valid JSON: {e.msg} at line {e.lineno}") from None
    return validate(rec, str(p))


def load_all(results_dir: str | Path = RESULTS_DIR) -> dict[str, dict[str, Any]]:
    """Every result file of ``results_dir`` by name, each checked."""
    return {p.stem: load(p) for p in sorted(Path(results_dir).glob("*.json"))}


def from_bench(raw: str | Path, name: str, title: str, command: str) -> dict[str, Any]:
    """A result record from the JSON of ``jaxenvs bench --json RAW``, run just before on
    this machine by ``command`` (the library's own format: its rows as they are)."""
    import jax  # noqa: F401  (loaded, so that machine() reports the GPU)

    d = json.loads(Path(raw).read_text())
    extra = {k: v for k, v in d.items() if k != "results"}
    return record(name, title, d["results"], extra=extra, argv=command.split())


def main(argv: list[str] | None = None) -> None:
    """``python benchmarks/results_io.py RAW.json NAME TITLE COMMAND``: wrap the output of
    ``jaxenvs bench --json RAW.json`` (which the package writes in its own format) as
    ``benchmarks/results/NAME.json``."""
    raw, name, title, command = sys.argv[1:] if argv is None else argv
    write(name, from_bench(raw, name, title, command))


if __name__ == "__main__":
    main()
