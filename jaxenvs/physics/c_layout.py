"""What a C step reads and writes of an ``mjx.Data`` (:class:`Layout`), the stand-in for a
field it does not provide (:class:`Unavailable`) and the models it cannot step: the data
contract of :mod:`jaxenvs.physics.cengine`."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

if TYPE_CHECKING:
    from mujoco import mjx

_S = mujoco.mjtState
_W = mujoco.mjtWarning

#: ``mjx.Data`` fields a C step reads
INPUTS = (
    "time",
    "qpos",
    "qvel",
    "act",
    "qacc_warmstart",
    "ctrl",
    "qfrc_applied",
    "xfrc_applied",
    "eq_active",
    "mocap_pos",
    "mocap_quat",
    "userdata",
)
#: the state a C step advances (inputs that are also outputs)
ADVANCED = ("time", "qpos", "qvel", "act", "qacc_warmstart")
#: warnings that mark a step as failed (see the module docstring)
BAD_WARNINGS = tuple(
    int(w)
    for w in (
        _W.mjWARN_CONTACTFULL,
        _W.mjWARN_CNSTRFULL,
        _W.mjWARN_BADQPOS,
        _W.mjWARN_BADQVEL,
        _W.mjWARN_BADQACC,
        _W.mjWARN_BADCTRL,
    )
)
#: below this many (envs x substeps x dofs) a batch is stepped on the calling thread (a
#: hand-off to the pool costs about as much as 64 dof-steps of a small model)
SERIAL_WORK = 64


class CEngineError(ValueError):
    """A model, a params field or a state field the C engine cannot step or provide."""


class Unavailable:
    """Stands in for an ``mjx.Data`` field the C engine does not provide.

    A pytree node with no leaves, so states holding it are jitted, vmapped, scanned and
    merged as usual; any use of it as a value (an attribute, an index, arithmetic,
    ``jnp.asarray``) raises :class:`CEngineError` naming the field.
    """

    __slots__ = ("name", "why")

    def __reduce__(self) -> tuple[Any, tuple[str, str]]:
        # copy and pickle rebuild it from its two names (its __getattr__ and
        # __setattr__ refuse every attribute, which the default protocol reads and sets)
        return (Unavailable, (self.name, self.why))

    def __init__(self, name: str, why: str = "layout") -> None:
        object.__setattr__(self, "name", name)
        #: ``"layout"`` (the C engine has no such field) or ``"undeclared"`` (the task's
        #: ``derived_fields`` leave it out, so the engine does not write it)
        object.__setattr__(self, "why", why)

    def fail(self) -> Any:
        if self.why == "undeclared":
            raise CEngineError(
                f"mjx.Data field {self.name!r} is not written by physics='c' for this task: "
                "add it to the task's derived_fields (the derived fields it reads)"
            )
        raise CEngineError(
            f"mjx.Data field {self.name!r} is not provided by physics='c' (MuJoCo C lays "
            "out contacts and constraints differently from MJX): read it under "
            "physics='mjx'"
        )

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("__"):
            raise AttributeError(attr)
        return self.fail()

    def __setattr__(self, attr: str, value: Any) -> None:
        self.fail()

    def __jax_array__(self) -> Any:
        return self.fail()

    def __array__(self, *args: Any, **kwargs: Any) -> Any:
        return self.fail()

    def __getitem__(self, key: Any) -> Any:
        return self.fail()

    def __bool__(self) -> bool:
        return bool(self.fail())

    def __len__(self) -> int:
        return int(self.fail())

    def __repr__(self) -> str:
        return f"Unavailable({self.name!r}: not provided by physics='c', {self.why})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Unavailable) and (other.name, other.why) == (self.name, self.why)

    def __hash__(self) -> int:
        return hash(("jaxenvs.physics.cengine.Unavailable", self.name, self.why))


def _fail_op(self: Unavailable, *args: Any) -> Any:
    return self.fail()


for _op in ("add", "sub", "mul", "truediv", "floordiv", "pow", "matmul", "mod"):
    setattr(Unavailable, f"__{_op}__", _fail_op)
    setattr(Unavailable, f"__r{_op}__", _fail_op)
for _op in ("neg", "pos", "abs", "lt", "le", "gt", "ge", "float", "int", "iter"):
    setattr(Unavailable, f"__{_op}__", _fail_op)

jax.tree_util.register_pytree_node(
    Unavailable, lambda u: ((), (u.name, u.why)), lambda aux, _: Unavailable(*aux)
)


@dataclasses.dataclass(frozen=True)
class Layout:
    """Which ``mjx.Data`` fields a C step reads and writes, for one model.

    Attributes:
      inputs: non-empty :data:`INPUTS` fields, in call order.
      outputs: ``(name, in_impl)`` of every field written (``in_impl``: a field of
        ``data._impl``), :data:`ADVANCED` first.
      unavailable: ``data._impl`` fields the C engine does not provide.
      shapes: each input's and output's shape for one env.
      skipped: ``(name, in_impl)`` of the derived fields it provides but does not write
        (those a task's ``derived_fields`` leave out).
    """

    inputs: tuple[str, ...]
    outputs: tuple[tuple[str, bool], ...]
    unavailable: tuple[str, ...]
    shapes: Mapping[str, tuple[int, ...]]
    skipped: tuple[tuple[str, bool], ...] = ()


def layout(
    model: mujoco.MjModel, template: mjx.Data, derived: Sequence[str] | None = None
) -> Layout:
    """The :class:`Layout` of ``model`` for an ``mjx.Data`` shaped like ``template``,
    writing every derived field it provides, or only those named in ``derived``."""
    if isinstance(derived, str):
        raise TypeError(
            f"derived_fields must be a tuple of field names, not the string {derived!r}"
        )
    c_data = mujoco.MjData(model)
    inputs: list[str] = []
    outputs: list[tuple[str, bool]] = [(n, False) for n in ADVANCED]
    unavailable: list[str] = []
    skipped: list[tuple[str, bool]] = []

    def write(name: str, in_impl: bool) -> None:
        (outputs if derived is None or name in derived else skipped).append((name, in_impl))

    shapes: dict[str, tuple[int, ...]] = {}

    def matches(name: str, leaf: Any) -> bool:
        if name == "actuator_moment":  # MJX dense (nu, nv); MuJoCo compressed rows
            return leaf.shape == (model.nu, model.nv)
        value = getattr(c_data, name, None)
        return (
            isinstance(value, np.ndarray)
            and value.dtype == np.float64
            and value.size == np.size(leaf)
            and jnp.issubdtype(leaf.dtype, jnp.floating)
        )

    for field in dataclasses.fields(template):
        name = field.name
        if name == "_impl":
            continue
        leaf = getattr(template, name)
        shapes[name] = np.shape(leaf)
        if name in INPUTS:
            if np.size(leaf) or name == "time":
                inputs.append(name)
        elif name not in ADVANCED and np.size(leaf) and matches(name, leaf):
            write(name, False)
        elif np.size(leaf) and name not in ("history", "plugin_state"):
            raise CEngineError(f"physics='c' has no value for mjx.Data field {name!r}")
    impl = template._impl
    for field in dataclasses.fields(impl):
        name = field.name
        leaf = getattr(impl, name)
        if isinstance(leaf, int | float | np.integer):  # sizes (ncon, nefc, ...)
            continue
        if isinstance(leaf, jax.Array | np.ndarray):
            shapes[name] = np.shape(leaf)
            if not np.size(leaf):
                continue
            if matches(name, leaf):
                write(name, True)
                continue
        unavailable.append(name)
    empty = {n for n, shape in shapes.items() if not math.prod(shape)}  # nothing to write
    known = {n for n, _ in outputs + skipped} | set(INPUTS) | empty
    unknown = sorted(set(derived or ()) - known)
    if unknown:
        raise CEngineError(
            f"derived_fields: {', '.join(unknown)} not among the mjx.Data fields "
            "physics='c' provides for this model"
        )
    return Layout(tuple(inputs), tuple(outputs), tuple(unavailable), shapes, tuple(skipped))


def check_model(model: mujoco.MjModel) -> None:
    """Raise :class:`CEngineError` for a model the C engine cannot step from an
    ``mjx.Data`` (state it does not carry: history, plugin state, plasticity)."""
    extra = {
        "history": int(_S.mjSTATE_HISTORY),
        "plugin state": int(_S.mjSTATE_PLUGIN),
        "plastic state": int(_S.mjSTATE_PLASTIC),
    }
    held = [name for name, spec in extra.items() if mujoco.mj_stateSize(model, spec)]
    if held:
        raise CEngineError(f"physics='c' does not step models with {', '.join(held)}")
