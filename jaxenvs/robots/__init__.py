"""The robot layer: one MJCF per robot family, shipped as package data."""

from __future__ import annotations

from pathlib import Path

ROBOT_DIR = Path(__file__).resolve().parent


def robot_xml(name: str) -> Path:
    """Path of the shipped MJCF for robot ``name`` (e.g. ``"cartpole"``)."""
    path = ROBOT_DIR / f"{name}.xml"
    if not path.is_file():
        known = sorted(p.stem for p in ROBOT_DIR.glob("*.xml"))
        raise ValueError(f"unknown robot {name!r}; shipped robots: {known}")
    return path
