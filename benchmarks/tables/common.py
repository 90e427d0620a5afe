"""What every table shares: the result-file types, the cell formats and the row look-ups.

A table is a :class:`Table`: the result files it is built from (stems under
``benchmarks/results/``) and the function that turns those records, in that order, into
cells (a header row, then one row per line). Cells are text, formatted here so that every
table prints a figure of the same kind the same way.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any, NamedTuple

Rec = dict[str, Any]
Row = dict[str, Any]
Cells = list[list[str]]


class ReportError(Exception):
    """A table that cannot be built from its files; the message names both."""


class Table(NamedTuple):
    """A generated table: its result files and the function that builds its cells."""

    files: tuple[str, ...]
    build: Callable[[list[Rec]], Cells]


# --- formatting ---------------------------------------------------------------------------

#: MuJoCo C's heightfield colliders (a terrain config's ``hfield_contact``), as tables name them
HFIELD_COLLIDERS = {"surface": "jaxenvs' surface", "mujoco": "MuJoCo's prisms"}


def rate(x: float) -> str:
    """Steps/s as the tables print them: 1.23M, 557k, 22.1k, 5,553."""
    if x >= 1e8:
        return f"{x / 1e6:.1f}M"
    if x >= 999_500:
        return f"{x / 1e6:.2f}M"
    if x >= 1e5:
        return f"{x / 1e3:,.0f}k"
    if x >= 1e4:
        return f"{x / 1e3:.1f}k"
    return f"{x:,.0f}"


def secs(x: float) -> str:
    return f"{x:.1f} s"


def ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}x"


def met(ok: bool) -> str:
    return "yes" if ok else "**no**"


def ret(mean: float, std: float) -> str:
    """A return and its spread at the precision its size needs."""
    digits = 1 if abs(mean) >= 100 else 2 if abs(mean) >= 1 else 3
    return f"{mean:.{digits}f} +- {std:.{digits}f}"


def pct(x: float) -> str:
    return f"{100 * x:.1f}%"


def sps(found: list[Row]) -> str:
    """Each row's env steps/s, in order: ``1.23M / 557k``."""
    return " / ".join(rate(r["env_steps_per_s"]) for r in found)


def first_calls(found: list[Row]) -> str:
    """Each row's first call, in order: ``1.2 s / 3.4 s``."""
    return " / ".join(secs(r["first_call_s"]) for r in found)


def target(what: str, ours: float, peer: float, bar: float) -> list[str]:
    """A target row: ``ours`` >= ``bar`` x ``peer``, the measured ratio and whether it is met."""
    return [what, f"{rate(ours)} / {rate(peer)} = **{ratio(ours, peer)}**", met(ours >= bar * peer)]


def table(cells: Cells) -> str:
    """The cells as a Markdown table, the first row its header."""
    head, *body = cells
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join("---" for _ in head) + " |"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in body]
    return "\n".join(lines)


def each_row(head: list[str], found: Iterable[Row], cells: Callable[[Row], list[str]]) -> Cells:
    """A table of one line per row: ``head``, then ``cells(row)`` for each row."""
    return [head, *(cells(r) for r in found)]


# --- looking rows up ----------------------------------------------------------------------


def rows(rec: Rec, **match: Any) -> list[Row]:
    """The record's rows whose fields equal ``match``."""
    return [r for r in rec["rows"] if all(r.get(k) == v for k, v in match.items())]


def one(rec: Rec, **match: Any) -> Row:
    """The one row matching; a :class:`ReportError` naming the file when not exactly one."""
    found = rows(rec, **match)
    if len(found) != 1:
        raise ReportError(f"{rec['name']}.json: {len(found)} rows match {match}, expected 1")
    return found[0]


def one_sps(rec: Rec, **match: Any) -> float:
    """The env steps/s of the one row matching."""
    return float(one(rec, **match)["env_steps_per_s"])


def maybe(rec: Rec, **match: Any) -> Row | None:
    """The first row matching that was not skipped, if any."""
    found = [r for r in rows(rec, **match) if not r.get("skipped")]
    return found[0] if found else None


def tasks(rec: Rec) -> Iterator[str]:
    """The tasks of our rows, in the record's order."""
    return iter(dict.fromkeys(r["task"] for r in rows(rec, name="jaxenvs")))


def ours(rec: Rec, task: str, physics: str | None = None) -> list[Row]:
    """Our rows for ``task`` (under ``physics``, where rows carry it), by batch size."""
    found = [r for r in rows(rec, name="jaxenvs", task=task) if not r.get("skipped")]
    if physics is not None:
        found = [r for r in found if r.get("physics", rec.get("engine")) == physics]
    return sorted(found, key=lambda r: r["num_envs"])


def best(found: list[Row]) -> Row:
    """The row with the most env steps/s."""
    return max(found, key=lambda r: r["env_steps_per_s"])


def best_sps(found: list[Row]) -> float:
    return float(best(found)["env_steps_per_s"])


def by_engine(recs: Iterable[Rec]) -> Iterator[tuple[Rec, str, list[Row], list[Row]]]:
    """``(record, task, MJX rows, C rows)`` for each of our tasks in each record, in order."""
    for rec in recs:
        for task in tasks(rec):
            yield rec, task, ours(rec, task, "mjx"), ours(rec, task, "c")
