"""``JaxVectorEnv``: N envs of a task as one ``gymnasium.vector.VectorEnv``."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from jaxenvs import registry
from jaxenvs.compat.gymnasium import checks
from jaxenvs.compat.gymnasium.programs import compiled
from jaxenvs.compat.gymnasium.words import Bufs
from jaxenvs.core import Env, State


class JaxVectorEnv(VectorEnv):
    """``num_envs`` copies of a jaxenvs task as a ``gymnasium.vector.VectorEnv``.

    Every ``step`` is one jitted call for all envs and one device-to-host copy. Auto-reset
    (``metadata["autoreset_mode"]``) as in Gymnasium's own vector envs:

    * ``NEXT_STEP`` (default): an env that finishes at step t returns its episode's last
      observation at t; at t+1 its action is ignored and it returns the first observation
      of a new episode, reward 0, ``terminated = truncated = False`` and no info keys.
    * ``SAME_STEP``: an env that finishes at step t returns the first observation of a new
      episode at t; ``info["final_obs"]`` (an object array, ``None`` where no episode
      ended) and ``info["final_info"]`` hold the finished episode's last observation and
      step info, each with its ``_``-prefixed mask.
    * ``DISABLED``: no auto-reset; reset the finished envs with
      ``reset(options={"reset_mask": mask})`` before the next ``step`` (which raises
      ``ResetNeeded`` otherwise).

    ``reset(options={"reset_mask": mask})`` resets the envs where ``mask`` is True in every
    mode. A fresh start is random, drawn with the env's own key.

    Args:
      env_id: a registered jaxenvs id (without the ``jaxenvs/`` prefix).
      num_envs: number of envs, stepped by one jitted vmapped function.
      max_episode_steps: the episode length (``make_vec`` passes the registered one);
        a different value overrides the task's ``episode_length``.
      autoreset_mode: a ``gymnasium.vector.AutoresetMode`` or its name (``"next_step"``,
        ``"same_step"``, ``"disabled"``) or value (``"NextStep"``, ...).
      randomize: draw per-env params at every reset (domain randomisation).
      devices: local devices the batch is spread over (default: all that ``num_envs``
        divides over; ``1``: none), as :func:`jaxenvs.make`.
      render_mode: ``None`` or ``"rgb_array"`` (``render()`` returns one frame per env).
      width, height, camera: frame size and camera.
      **overrides: fields of the task's config.
    """

    metadata: dict[str, Any] = {
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": checks.DECLARED_MODES,
        "render_fps": 50,
    }

    def __init__(
        self,
        env_id: str,
        num_envs: int = 1,
        max_episode_steps: int | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        randomize: bool = False,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | int | None = None,
        devices: int | None = None,
        **overrides: Any,
    ) -> None:
        checks.check_render_mode(render_mode)
        mode = checks.autoreset_mode(autoreset_mode)
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        if max_episode_steps is not None:
            default = registry.make_config(env_id, overrides).episode_length
            if int(max_episode_steps) != default:
                overrides["episode_length"] = int(max_episode_steps)
        self._fns = compiled(env_id, overrides, num_envs, bool(randomize), devices, mode)
        self.env_id = env_id
        self.autoreset_mode = mode
        self.jax_env: Env = self._fns.env
        self.num_envs = num_envs
        self.single_observation_space = self.jax_env.observation_space
        self.single_action_space = self.jax_env.action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.render_mode = render_mode
        self.metadata = {
            "autoreset_mode": mode,
            "render_modes": checks.RENDER_MODES,
            "render_fps": checks.render_fps(self.jax_env),
        }
        self._render_args = (width, height, camera)
        self._renderer: Any = None
        self._bufs: Bufs | None = None
        #: envs whose episode ended at the last step (NEXT_STEP: reset at the next step)
        self._ended = np.zeros(num_envs, dtype=bool)

    @property
    def state(self) -> State | None:
        """The current batched functional-API state (``None`` before the first reset)."""
        return None if self._bufs is None else self._fns.unpack(self._bufs)

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every env (or those of ``options["reset_mask"]``). ``seed`` as
        ``SyncVectorEnv`` takes it: an int ``s`` seeds env i with ``s + i`` (and
        ``np_random`` with ``s``); a list gives one seed (or None) per env; env i seeded
        with ``s`` starts where ``gymnasium.make``'s env starts after ``reset(seed=s)``."""
        checks.check_open(self.closed, self.env_id)
        seeds = checks.env_seeds(seed, self.num_envs, self.np_random)
        if isinstance(seed, (int, np.integer)):
            super().reset(seed=int(seed))  # np_random, which later unseeded resets draw from
        opts = checks.check_options(options, ("reset_mask",))
        if "reset_mask" not in opts:
            self._bufs = self._fns.reset(seeds)
            self._ended[:] = False
        else:
            mask = checks.check_reset_mask(opts["reset_mask"], self.num_envs)
            if self._bufs is None:
                raise ResetNeeded("reset with a reset_mask needs a full reset() first")
            assert self._fns.reset_masked is not None
            self._bufs = self._fns.reset_masked(self._bufs, seeds, mask)
            self._ended[mask] = False
        return self._fns.words.report_batch(self._bufs)["obs"], {}

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        checks.check_open(self.closed, self.env_id)
        if self._bufs is None:
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        if self.autoreset_mode is AutoresetMode.DISABLED and self._ended.any():
            raise ResetNeeded(
                f"envs {np.flatnonzero(self._ended).tolist()} finished at the last step; with "
                "autoreset_mode=DISABLED reset them first: reset(options={'reset_mask': mask})"
            )
        actions = checks.check_action(self.jax_env, actions, self.num_envs)
        self._bufs = self._fns.step(self._bufs, actions)
        out = self._fns.words.report_batch(self._bufs)
        obs, rewards = out.pop("obs"), out.pop("reward")
        terminated, truncated = out.pop("terminated"), out.pop("truncated")
        final_obs = out.pop("final_obs", None)
        if self.autoreset_mode is AutoresetMode.NEXT_STEP:
            # the envs that ended at the last step were reset in this one: no step info
            infos = _infos(out, ~self._ended)
        elif self.autoreset_mode is AutoresetMode.SAME_STEP:
            infos = _same_step_infos(out, final_obs, terminated | truncated)
        else:
            infos = _infos(out, np.ones(self.num_envs, dtype=bool))
        self._ended = terminated | truncated
        return obs, rewards, terminated, truncated, infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() called without a render_mode; pass render_mode='rgb_array'"
            )
            return None
        checks.check_open(self.closed, self.env_id)
        if self._bufs is None:
            raise ResetNeeded("Cannot call render() before calling reset()")
        if self._renderer is None:
            from jaxenvs.render import Renderer

            self._renderer = Renderer(self.jax_env, *self._render_args)
        state = self.state
        assert state is not None
        data = state.data
        qpos, mpos, mquat = (np.asarray(x) for x in (data.qpos, data.mocap_pos, data.mocap_quat))
        return tuple(self._renderer.frame(qpos[i], mpos[i], mquat[i]) for i in range(self.num_envs))

    def close_extras(self, **kwargs: Any) -> None:
        """Release the renderer and the state; a closed env refuses ``reset``, ``step``
        and ``render`` (``ClosedEnvironmentError``)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._bufs = None


def _infos(values: dict[str, np.ndarray], reporting: np.ndarray) -> dict[str, Any]:
    """Step infos as ``SyncVectorEnv`` merges them: every key with its mask of the envs
    that report it; no key where none does."""
    if not reporting.any():
        return {}
    infos: dict[str, Any] = {}
    for k, v in values.items():
        infos[k], infos[f"_{k}"] = v, reporting.copy()
    return infos


def _same_step_infos(
    values: dict[str, np.ndarray], final_obs: np.ndarray | None, done: np.ndarray
) -> dict[str, Any]:
    """SAME_STEP infos: finished envs report their last step under ``final_obs`` /
    ``final_info``; the top-level info of an auto-reset env is its (empty) reset info."""
    if not done.any():
        return _infos(values, np.ones_like(done))
    assert final_obs is not None
    infos = _infos(values, ~done)
    last = np.full(len(done), None, dtype=object)
    for i in np.flatnonzero(done):
        last[i] = final_obs[i]
    infos["final_obs"], infos["_final_obs"] = last, done
    infos["final_info"], infos["_final_info"] = _infos(values, done), done
    return infos
