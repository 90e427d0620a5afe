"""The robot layer: one folder per robot family, holding its MJCF (package data) and its
robot module (:mod:`jaxenvs.robots.base` says what a robot is)."""

from __future__ import annotations

from pathlib import Path

ROBOT_DIR = Path(__file__).resolve().parent


def robot_xml(name: str) -> Path:
    """Path of the shipped MJCF ``name`` (e.g. ``"cartpole"``, ``"hexapod_leg"``), found in
    its robot family's folder."""
    found = sorted(ROBOT_DIR.glob(f"*/{name}.xml"))
    if len(found) != 1:
        known = sorted(p.stem for p in ROBOT_DIR.glob("*/*.xml"))
        raise ValueError(f"unknown robot {name!r}; shipped robots: {known}")
    return found[0]
