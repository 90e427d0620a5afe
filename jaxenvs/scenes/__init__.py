"""Scenes: a robot on its ground (a flat floor or a terrain)."""
