"""The battery every registered id passes (see jaxenvs.testing)."""

from __future__ import annotations

import pytest

import jaxenvs

IDS = jaxenvs.list_envs()


@pytest.mark.parametrize("env_id", IDS)
def test_single_trace(get_checker, env_id):
    get_checker(env_id).check_single_trace()


@pytest.mark.parametrize("env_id", IDS)
def test_determinism(get_checker, env_id):
    get_checker(env_id).check_determinism()


@pytest.mark.parametrize("env_id", IDS)
def test_spaces(get_checker, env_id):
    get_checker(env_id).check_spaces()


@pytest.mark.parametrize("env_id", IDS)
def test_vmap_matches_single(get_checker, env_id):
    get_checker(env_id).check_vmap_matches()


@pytest.mark.parametrize("env_id", IDS)
def test_random_rollout(get_checker, env_id):
    get_checker(env_id).check_rollout()
