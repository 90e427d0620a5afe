"""The sim layer: the MJX world a robot lives in.

A :class:`Sim` owns one compiled MuJoCo model (host ``mujoco.MjModel`` for rendering and
parity checks, device ``mjx.Model`` for stepping), the physics timestep and the number
of substeps per control step. Everything it does on device is a pure function of
``(model, data, ...)``; randomisable physical quantities enter through
:meth:`Sim.model_with`, which swaps model fields for values carried in a params pytree.

The device model is the host model without what only a picture needs (:func:`physics_model`):
cameras, lights and geoms that collide with nothing. MJX computes every such element's
pose in each physics step; for the small robots that was most of the step's kinematics
(benchmarks/NOTES.md). Bodies, joints, sites, actuators and colliding geoms keep their ids,
so ids looked up on the host model index device data too; rendering uses the host model.
"""

from __future__ import annotations

import contextlib
import functools
import io
from collections.abc import Callable, Mapping
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Protocol

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

if TYPE_CHECKING:
    from mujoco import mjx

Controller = Callable[["mjx.Data"], jax.Array]


@functools.cache
def mjx_module() -> ModuleType:
    """``mujoco.mjx``, imported on first use: importing it takes most of a second, which a
    process that never builds an MJX model (``import jaxenvs``, the CLI's help, listing
    envs) does not pay. It prints a notice when its optional Warp backend is absent; the
    import is kept quiet."""
    with contextlib.redirect_stdout(io.StringIO()):
        from mujoco import mjx
    return mjx


class SpecSource(Protocol):
    """A model source other than a file: a scene."""

    def spec(self) -> mujoco.MjSpec: ...


#: what a Sim is compiled from: an MJCF file or a scene
Source = str | Path | SpecSource


class Sim:
    """One MJX world: model, timestep, substeps.

    Args:
      xml: path of the MJCF file, or a scene (:class:`jaxenvs.scenes.Scene`: anything
        with ``spec()`` returning a fresh :class:`mujoco.MjSpec`).
      timestep: physics timestep in seconds (overrides the MJCF's).
      substeps: physics steps per control step.
      edit: optional function applied to the host ``MjModel`` before it is put on
        device (e.g. to change an actuator's gain for one task); it is applied to the
        device model's host copy too, so it must not index geoms, cameras or lights.
      lean: put :func:`physics_model` on device instead of the full host model.
    """

    def __init__(
        self,
        xml: Source,
        timestep: float,
        substeps: int,
        edit: Callable[[mujoco.MjModel], None] | None = None,
        lean: bool = True,
    ) -> None:
        if timestep <= 0:
            raise ValueError(f"timestep must be positive, got {timestep}")
        if substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        #: the MJCF file or scene (:class:`jaxenvs.scenes.Scene`) the world is compiled from
        self.source = xml
        self.edit = edit
        self.lean = lean
        if lean:
            self.mj_model, lean_model = _full_and_lean(xml)
        else:
            self.mj_model = lean_model = _spec(xml).compile()
        self.mj_model.opt.timestep = timestep
        #: the host model the device model was made from (== ``mj_model`` unless lean)
        self.physics_mj_model = lean_model
        self.physics_mj_model.opt.timestep = timestep
        if edit is not None:
            edit(self.mj_model)
            if lean:
                edit(self.physics_mj_model)
        # on this process's first device: MJX's default, jax.devices()[0], is process 0's
        # in a run over several hosts (jaxenvs.run.distributed)
        here = jax.local_devices()[0]
        self.mx = mjx_module().put_model(self.physics_mj_model, device=here)
        self.substeps = int(substeps)
        self.timestep = float(timestep)
        # from the host model: the same Data as from ``self.mx`` (tested), built with numpy
        # so that making an env compiles no eager JAX op
        self._data0 = mjx_module().make_data(self.physics_mj_model, device=here)

    @property
    def control_dt(self) -> float:
        """Seconds of simulated time per control step."""
        return self.timestep * self.substeps

    #: the physics engine that steps this world (``"mjx"``; :class:`CSim` is ``"c"``)
    physics = "mjx"

    def with_physics(
        self,
        physics: str,
        threads: int | None = None,
        derived: tuple[str, ...] | None = None,
    ) -> Sim:
        """This world stepped by ``physics``: ``"mjx"`` (itself) or ``"c"`` (:class:`CSim`,
        writing only the ``derived`` fields when given)."""
        if physics == "mjx":
            return self
        if physics == "c":
            return CSim(self, threads, derived)
        raise ValueError(f"physics must be 'mjx' or 'c', got {physics!r}")

    def model_with(self, fields: Mapping[str, jax.Array]) -> Any:
        """The device model with top-level fields replaced (e.g. ``body_mass``)."""
        if not fields:
            return self.mx
        return self.mx.replace(**fields)

    def select_data(
        self, pick: Callable[[jax.Array, jax.Array], jax.Array], new: mjx.Data, old: mjx.Data
    ) -> mjx.Data:
        """``pick(new_leaf, old_leaf)`` over the fields of two states that a step carries
        (all of them under MJX); used by the auto-reset to merge fresh starts in."""
        return jax.tree.map(pick, new, old)

    def default_fields(self, names: tuple[str, ...]) -> dict[str, jax.Array]:
        """Current values of model fields, for building a task's default params."""
        return {name: jnp.asarray(getattr(self.mx, name)) for name in names}

    def init_data(self, qpos: jax.Array, qvel: jax.Array, **fields: jax.Array) -> mjx.Data:
        """A fresh ``mjx.Data`` with ``qpos``/``qvel`` (and e.g. ``mocap_pos``) set.

        Kinematics are not recomputed here; call :meth:`forward` when the observation
        needs positions derived from ``qpos`` before the first step.
        """
        return self._data0.replace(qpos=qpos, qvel=qvel, **fields)

    def step(self, model: Any, data: mjx.Data, ctrl: jax.Array) -> mjx.Data:
        """Hold ``ctrl`` for one control step (``substeps`` MJX physics steps)."""
        data = data.replace(ctrl=jnp.asarray(ctrl, data.ctrl.dtype))
        if self.substeps == 1:
            return mjx_module().step(model, data)

        def body(d: mjx.Data, _: None) -> tuple[mjx.Data, None]:
            return mjx_module().step(model, d), None

        data, _ = jax.lax.scan(body, data, None, length=self.substeps)
        return data

    def forward(self, model: Any, data: mjx.Data) -> mjx.Data:
        """Every derived field (positions, velocities, forces) at ``data``'s state, as
        ``mjx.forward``; pass ``self.model_with(fields)`` as for :meth:`step`."""
        return mjx_module().forward(model, data)

    def step_controlled(self, model: Any, data: mjx.Data, controller: Controller) -> mjx.Data:
        """One control step where ``controller(data) -> ctrl`` runs before every substep.

        This is how a robot-level low-level controller (e.g. a velocity servo that
        outputs motor commands) runs at the physics rate under a slower policy.
        """

        def body(d: mjx.Data, _: None) -> tuple[mjx.Data, None]:
            ctrl = jnp.asarray(controller(d), d.ctrl.dtype)
            return mjx_module().step(model, d.replace(ctrl=ctrl)), None

        data, _ = jax.lax.scan(body, data, None, length=self.substeps)
        return data


class CSim(Sim):
    """The same world stepped by MuJoCo's C engine on the CPU (:mod:`jaxenvs.physics.cengine`).

    Built from a :class:`Sim`: the same host model, timestep, substeps and edits, so ids,
    default params and rendering are unchanged. :meth:`model_with` returns the fields
    themselves (the C engine applies them per env), :meth:`step`, :meth:`step_controlled`
    and :meth:`forward` call the C engine, and states hold
    :class:`jaxenvs.physics.cengine.Unavailable` where the C engine provides no value (the contact
    and constraint arrays) or, given ``derived`` (a task's ``derived_fields``), writes none
    (every derived field but those).
    """

    physics = "c"

    def __init__(  # noqa: D107
        self, base: Sim, threads: int | None = None, derived: tuple[str, ...] | None = None
    ) -> None:
        from jaxenvs import machine
        from jaxenvs.physics import cengine

        if jax.default_backend() != "cpu":
            raise ValueError(
                f"physics='c' steps MuJoCo's C engine on the CPU, but JAX's default backend "
                f"is {jax.default_backend()!r}: use physics='mjx' (or 'auto') there, or run "
                "with JAX_PLATFORMS=cpu"
            )
        self.__dict__.update(base.__dict__)
        self.engine = cengine.CEngine(
            base.physics_mj_model,
            base._data0,
            threads or machine.cpu_threads(),
            derived=derived,
        )
        self._data0 = self.engine.blank(base._data0)
        #: the derived fields the engine writes (``None``: every one it provides)
        self.derived = None if derived is None else tuple(derived)

    def with_physics(
        self,
        physics: str,
        threads: int | None = None,
        derived: tuple[str, ...] | None = None,
    ) -> Sim:
        same = (None if derived is None else tuple(derived)) == self.derived
        if physics == "c" and (threads is None or threads == self.engine.threads) and same:
            return self
        raise ValueError("build a C world from the MJX Sim it was made from")

    def model_with(self, fields: Mapping[str, jax.Array]) -> dict[str, jax.Array]:
        """The params fields themselves; the C engine applies them per env."""
        return dict(fields)

    def step(self, model: Any, data: mjx.Data, ctrl: jax.Array) -> mjx.Data:
        return self.engine.step(_fields(model), data, ctrl, self.substeps)

    def step_controlled(self, model: Any, data: mjx.Data, controller: Controller) -> mjx.Data:
        fields = _fields(model)

        def body(d: mjx.Data, _: None) -> tuple[mjx.Data, None]:
            return self.engine.step(fields, d, controller(d), 1), None

        data, _ = jax.lax.scan(body, data, None, length=self.substeps)
        return data

    def forward(self, model: Any, data: mjx.Data) -> mjx.Data:
        """The derived fields this world writes (every one, or ``derived``'s) at
        ``data``'s state."""
        return self.engine.forward(_fields(model), data)


def _fields(model: Any) -> Mapping[str, jax.Array]:
    if isinstance(model, Mapping):
        return model
    if model is None:
        return {}
    raise TypeError(
        "physics='c': pass sim.model_with(fields) (or None) to sim.step, not an mjx.Model"
    )


_INERTIAL = ("body_mass", "body_inertia", "body_ipos", "body_iquat")


def physics_model(xml: Source) -> mujoco.MjModel:
    """The MJCF at ``xml`` without cameras, lights and geoms that collide with nothing.

    A geom is dropped when its ``contype`` and ``conaffinity`` are both 0 and no contact
    ``<pair>`` names it. Every body's inertia is first frozen at the value the full model
    computes (from its geoms or its ``<inertial>``), so masses, inertias and the dynamics
    are unchanged; a ValueError says so if they were not. Sites stay (tasks read them).
    """
    return _full_and_lean(xml)[1]


def _full_and_lean(xml: Source) -> tuple[mujoco.MjModel, mujoco.MjModel]:
    """The full model at ``xml`` and :func:`physics_model`'s lean copy, each compiled once."""
    full, spec = _lean_spec(xml)
    lean = spec.compile()
    for field in _INERTIAL:
        if lean.nbody != full.nbody or not np.allclose(
            getattr(lean, field), getattr(full, field), rtol=1e-9, atol=1e-12
        ):
            raise ValueError(f"{xml}: dropping visual elements changed {field}")
    return full, lean


def _spec(source: Source) -> mujoco.MjSpec:
    """A fresh spec of an MJCF file or of a scene (anything with ``spec()``)."""
    if isinstance(source, str | Path):
        return mujoco.MjSpec.from_file(str(source))
    return source.spec()


def _lean_spec(xml: Source) -> tuple[mujoco.MjModel, mujoco.MjSpec]:
    """The full model at ``xml`` and the spec of its lean copy (not yet compiled)."""
    spec = _spec(xml)
    full = spec.compile()
    bodies = spec.bodies
    if len(bodies) != full.nbody:
        raise ValueError(f"{xml}: {len(bodies)} bodies in the spec, {full.nbody} compiled")
    for i, body in enumerate(bodies[1:], start=1):  # 0 is the world
        body.explicitinertial = True
        body.mass = full.body_mass[i]
        body.ipos = full.body_ipos[i]
        body.iquat = full.body_iquat[i]
        body.inertia = full.body_inertia[i]
    paired = {name for p in spec.pairs for name in (p.geomname1, p.geomname2)}
    for geom in list(spec.geoms):
        if geom.contype == 0 and geom.conaffinity == 0 and geom.name not in paired:
            spec.delete(geom)
    for element in [*spec.cameras, *spec.lights]:
        spec.delete(element)
    return full, spec


def forward(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """Recompute derived quantities (positions, velocities) from ``qpos``/``qvel``."""
    return mjx_module().forward(model, data)
