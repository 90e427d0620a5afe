"""The battery every registered id passes (see jaxenvs.testing).

Default tier: each id on the engine ``jaxenvs.make`` picks here (MuJoCo's C engine on a
CPU: the battery checks the task's code, which both engines share). Full tier: each id
again on MJX, whose compile is what makes it long (the walker's about a minute on 2 cores).
"""

from __future__ import annotations

import pytest

import jaxenvs

# the built-in ids only: a user task registered by another test module of this folder
# (the custom-task example) is checked there
IDS = [i for i in jaxenvs.list_envs() if jaxenvs.spec(i).factory.__module__.startswith("jaxenvs.")]
ENGINES = [pytest.param("auto", id="auto"), pytest.param("mjx", id="mjx", marks=pytest.mark.full)]

pytestmark = [pytest.mark.parametrize("physics", ENGINES), pytest.mark.parametrize("env_id", IDS)]


def test_single_trace(get_checker, env_id, physics):
    get_checker(env_id, physics).check_single_trace()


def test_determinism(get_checker, env_id, physics):
    get_checker(env_id, physics).check_determinism()


def test_keys(get_checker, env_id, physics):
    get_checker(env_id, physics).check_keys()


def test_spaces(get_checker, env_id, physics):
    get_checker(env_id, physics).check_spaces()


def test_vmap_matches_single(get_checker, env_id, physics):
    get_checker(env_id, physics).check_vmap_matches()


def test_random_rollout(get_checker, env_id, physics):
    get_checker(env_id, physics).check_rollout()
