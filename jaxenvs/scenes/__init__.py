"""Scenes: a robot on its ground.

The robot's folder (:mod:`jaxenvs.robots`) holds the robot alone: its bodies, joints,
actuators and sensors. A :class:`Scene` composes it with a ground (:class:`Flat`, a floor;
a terrain of levels x types, :mod:`jaxenvs.scenes.terrain`), the contact pairs between the
robot's contact geoms (the hexapod's feet) and that ground, a light, and a task's markers
(the walker's target). A task names its scene; :class:`jaxenvs.physics.sim.Sim` compiles
it (:meth:`Scene.spec`) as it compiles an MJCF file.

A ground is any frozen object with ``name`` (the geom the pairs name), ``friction``
(the pairs' friction: an explicit pair's friction is its own, not the geoms' mix) and
``add_to(spec)`` (it adds its geoms and assets to a :class:`mujoco.MjSpec`'s world body).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Protocol

import mujoco

from jaxenvs.physics import native
from jaxenvs.physics.native import HFIELD_SURFACE

#: the floor's friction (sliding, torsional, rolling) and the default ground's size (m)
FLOOR_FRICTION = (1.0, 0.005, 0.0001)
#: the name of the model ``<numeric>`` MJX reads as its contact budget (``Scene.max_contacts``)
MAX_CONTACTS = "max_contact_points"
#: :attr:`Scene.hfield_contact`'s choices
HFIELD_CONTACTS = ("surface", "mujoco")


class Ground(Protocol):
    """What a :class:`Scene` needs of its ground."""

    @property
    def name(self) -> str:
        """The name of the geom the robot's contact pairs name."""
        ...

    @property
    def friction(self) -> tuple[float, float, float]:
        """Sliding, torsional and rolling friction of the robot's contacts with it."""
        ...

    def add_to(self, spec: mujoco.MjSpec) -> None:
        """Add the ground's geoms (and their assets) to ``spec``'s world body."""
        ...


@dataclasses.dataclass(frozen=True)
class Flat:
    """A flat floor: a plane through z = 0, drawn ``size`` m from the origin each way with a
    checker texture.

    Attributes:
      size: the half-width drawn (m); the plane collides everywhere.
      friction: sliding, torsional and rolling friction of the floor's geom.
    """

    size: float = 20.0
    friction: tuple[float, float, float] = FLOOR_FRICTION
    name: str = "floor"

    def add_to(self, spec: mujoco.MjSpec) -> None:
        texture = spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D)
        texture.builtin = mujoco.mjtBuiltin.mjBUILTIN_CHECKER
        texture.rgb1 = [0.15, 0.2, 0.25]
        texture.rgb2 = [0.2, 0.25, 0.3]
        texture.width = texture.height = 256
        material = spec.add_material(name="grid", texrepeat=[20, 20], reflectance=0.1)
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
        spec.worldbody.add_geom(
            name=self.name,
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[self.size, self.size, 0.1],
            material="grid",
            friction=list(self.friction),
        )


@dataclasses.dataclass(frozen=True)
class Marker:
    """A mocap body drawn as a flat disc (the walker's target): no mass in the dynamics,
    collides with nothing; the task moves it through ``data.mocap_pos``.

    Attributes:
      name: the body's and geom's name.
      pos: its initial position (m).
      radius, half_height: the disc's size (m).
      rgba: its colour.
    """

    name: str
    pos: tuple[float, float, float] = (1.0, 0.0, 0.01)
    radius: float = 0.05
    half_height: float = 0.005
    rgba: tuple[float, float, float, float] = (0.9, 0.2, 0.2, 0.6)

    def mjcf(self) -> str:
        """The marker as an MJCF ``<body>`` element (its geom takes the robot file's
        default class, as every geom there: it collides with nothing)."""
        x, y, z = self.pos
        r, g, b, a = self.rgba
        return (
            f'<body name="{self.name}" mocap="true" pos="{x} {y} {z}">'
            f'<geom name="{self.name}" type="cylinder" size="{self.radius} {self.half_height}"'
            f' rgba="{r} {g} {b} {a}"/></body>'
        )


@dataclasses.dataclass(frozen=True)
class Scene:
    """A robot on its ground, compiled by :class:`~jaxenvs.physics.sim.Sim` as an MJCF
    file is.

    Attributes:
      robot: the robot's MJCF (its folder's file: the robot alone).
      ground: the ground (:class:`Flat`, or a terrain).
      contacts: the robot's geoms paired with the ground (one explicit contact pair each,
        in this order: the only collisions of the scene), with the ground's friction
        (sliding on both tangent axes, torsional, rolling on both axes).
      markers: the task's markers (mocap bodies, in ``mocap_pos`` order).
      light: a light 4 m above the origin, pointing down.
      max_contacts: under MJX, the most contacts a step keeps of each contact dimension
        (the deepest; MJX's ``max_contact_points``, a ``<numeric>`` of the model: with
        pairs of one ``condim``, as a robot's feet on its ground, the step's), 0 for
        every contact slot of the scene's pairs (each pair has as many slots as its
        collision function returns: 1 for a sphere on a plane, 4 for a sphere on a
        heightfield). MuJoCo C keeps every contact whatever this says.
      hfield_contact: how MuJoCo C collides the robot's spheres with a heightfield ground:
        ``"surface"`` (jaxenvs' collider, :func:`jaxenvs.physics.native.hfield_surface`:
        the sphere on the triangles MuJoCo draws, one contact per local minimum of the
        distance, so flat cells give one vertical contact) or ``"mujoco"`` (MuJoCo's own,
        the cells' triangular prisms as convex solids: normals tilted by up to 60 degrees
        on flat cells, docs/terrain.md). ``"surface"`` writes the model ``<numeric>``
        :data:`~jaxenvs.physics.native.HFIELD_SURFACE` and installs the collider in the
        process (where the native library is not built, the C engine warns when it meets
        such a model and steps MuJoCo's). MJX has its own collider either way.
    """

    robot: Path
    ground: Ground = Flat()
    contacts: tuple[str, ...] = ()
    markers: tuple[Marker, ...] = ()
    light: bool = True
    max_contacts: int = 0
    hfield_contact: str = "surface"

    def __post_init__(self) -> None:
        if self.max_contacts < 0:
            raise ValueError(f"max_contacts must be >= 0, got {self.max_contacts}")
        if self.hfield_contact not in HFIELD_CONTACTS:
            raise ValueError(
                f"hfield_contact must be one of {HFIELD_CONTACTS}, got {self.hfield_contact!r}"
            )

    @property
    def name(self) -> str:
        """``<robot file> on <ground>``, for messages."""
        return f"{Path(self.robot).name} on {type(self.ground).__name__.lower()}"

    def __str__(self) -> str:
        return self.name

    def spec(self) -> mujoco.MjSpec:
        """A fresh :class:`mujoco.MjSpec` of the scene (not compiled).

        The markers come first among the world's bodies, before the robot's (as they stood
        in the robot's MJCF before the scene was split from it: a randomised body's draw
        is indexed by body, so the order keeps those draws); the ground's geoms are the
        world body's own, first among the geoms."""
        robot = Path(self.robot)
        text = robot.read_text()
        if self.markers:
            if text.count("<worldbody>") != 1:
                raise ValueError(f"{robot}: expected one <worldbody> element")
            bodies = "".join(marker.mjcf() for marker in self.markers)
            text = text.replace("<worldbody>", "<worldbody>" + bodies, 1)
        spec = mujoco.MjSpec.from_string(text)
        spec.meshdir = str(robot.parent / spec.meshdir) if spec.meshdir else str(robot.parent)
        if self.light:
            spec.worldbody.add_light(name="top", pos=[0, 0, 4], dir=[0, 0, -1])
        self.ground.add_to(spec)
        slide, torsion, roll = self.ground.friction
        for geom in self.contacts:
            spec.add_pair(
                geomname1=self.ground.name,
                geomname2=geom,
                friction=[slide, slide, torsion, roll, roll],
            )
        if self.max_contacts:
            spec.add_numeric(name=MAX_CONTACTS, data=[float(self.max_contacts)])
        hfields = any(g.type == mujoco.mjtGeom.mjGEOM_HFIELD for g in spec.worldbody.geoms)
        if hfields and self.hfield_contact == "surface":
            spec.add_numeric(name=HFIELD_SURFACE, data=[1.0])
            native.hfield_surface()  # installed now, for any MuJoCo C step of the process
        return spec


__all__ = ["FLOOR_FRICTION", "HFIELD_CONTACTS", "MAX_CONTACTS", "Flat", "Ground", "Marker", "Scene"]
