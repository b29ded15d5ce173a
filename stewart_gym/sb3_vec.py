"""Stable-Baselines3's :class:`~stable_baselines3.common.vec_env.VecEnv` over the batched vector env
(:class:`~stewart_gym.envs.vector.StewartBallVectorEnv`): ``train --backend batched`` steps its copies through it.

A residual recipe's correction (``residual``) is mixed in here, copy by copy, exactly as
:class:`~stewart_gym.sb3_models.ResidualAction` does for one env. Stack :class:`VecMonitor` on top for episode
statistics, as training does.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from stewart_gym.errors import ConfigError
from stewart_gym.sb3_models import check_residual, residual_base, residual_mix

__all__ = ["BatchedVecEnv"]


class BatchedVecEnv(VecEnv):
    """``num_envs`` copies of ``env_id`` on one batched simulator, as SB3 steps them.

    Args:
        env_id: A registered id.
        num_envs: How many copies.
        env_kwargs: The env's keywords (``backend`` may be ``"batched"`` or absent; not ``workers``).
        residual: A residual spec (:func:`~stewart_gym.sb3_models.check_residual`): each copy's action corrects
            its own classical controller's.
    """

    def __init__(self, env_id: str, num_envs: int, env_kwargs: dict[str, Any] | None = None,
                 residual: dict[str, Any] | None = None) -> None:  # fmt: skip
        kwargs = {k: v for k, v in (env_kwargs or {}).items() if k != "backend"}
        backend = (env_kwargs or {}).get("backend", "batched")
        if backend != "batched":
            raise ConfigError(f"env_kwargs.backend: this VecEnv steps the batched backend, got {backend!r} (for "
                              "PyBullet or MuJoCo copies use DummyVecEnv or SubprocVecEnv)")  # fmt: skip
        if kwargs.get("workers", 1) != 1:
            raise ConfigError(f"env_kwargs.workers: training steps its batched copies in one process (got "
                              f"{kwargs['workers']!r}); leave workers out, or use gym.make_vec(..., workers=k) "
                              "outside training")  # fmt: skip
        self.venv = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)
        super().__init__(num_envs, self.venv.single_observation_space, self.venv.single_action_space)
        self._actions: np.ndarray | None = None
        self._obs: np.ndarray | None = None
        self.mixes: list[Any] = []
        self.bases: list[Any] = []
        if residual:
            spec = check_residual(residual)
            first = self.venv.envs[0]
            dt = 1.0 / first.sim.control_hz
            self.bases = [residual_base(spec, first.sim.geometry, first.plate_half_extent, dt) for _ in range(num_envs)]
            self.mixes = [residual_mix(spec, first.plate_half_extent, dt) for _ in range(num_envs)]

    def reset(self) -> np.ndarray:
        """Every copy's first observation: seeded and with the options given since the last reset (``seed``,
        ``set_options``), as DummyVecEnv resets; each copy's reset info in :attr:`reset_infos`."""
        seeds = list(self._seeds) if any(s is not None for s in self._seeds) else None
        options = self._options[0] if self._options else {}
        if not all(_same(o, options) for o in self._options):
            raise ConfigError("set_options: the batched copies reset with one set of options; give every copy the "
                              "same (a dict), or reset them with DummyVecEnv")  # fmt: skip
        obs, columns = self.venv.reset_arrays(seed=seeds, options=options or None)
        keys = list(columns)
        self.reset_infos = [dict(zip(keys, row)) for row in zip(*(columns[key] for key in keys))]
        self._reset_seeds()
        self._reset_options()
        for base, mix in zip(self.bases, self.mixes):
            base.reset()
            mix.reset()
        self._obs = obs
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        if self._actions is None or self._obs is None:
            raise RuntimeError("call reset, then step_async, before step_wait")
        actions = self._actions
        if self.bases:
            actions = np.stack([mix(base(o), a, o) for base, mix, o, a in zip(self.bases, self.mixes, self._obs, actions)])
        obs, rewards, terminated, truncated, infos, finals = self.venv.step_each(actions)
        for i, (final_obs, final_info) in finals.items():  # as DummyVecEnv: the ended episode's info, its reset's apart
            self.reset_infos[i] = infos[i]
            infos[i] = {**final_info, "terminal_observation": final_obs,
                        "TimeLimit.truncated": bool(truncated[i] and not terminated[i])}  # fmt: skip
            if self.bases:
                self.bases[i].reset()
                self.mixes[i].reset()
        self._obs = obs
        return obs, rewards, terminated | truncated, infos

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self.venv.envs[i], attr_name) for i in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        for i in self._get_indices(indices):
            setattr(self.venv.envs[i], attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any) -> list[Any]:
        return [getattr(self.venv.envs[i], method_name)(*method_args, **method_kwargs) for i in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> Sequence[bool]:
        return [False for _ in self._get_indices(indices)]


def _same(a: Any, b: Any) -> bool:
    """Whether two copies' reset options are the same (options holding arrays that differ, or cannot be compared
    as a whole, are not)."""
    try:
        return a is b or bool(a == b)
    except ValueError:  # arrays of several numbers: no one truth value
        return False
