"""Stable-Baselines3 models with the observation normalisation they were trained with.

:func:`load_sb3` reads a PPO, SAC or TD3 model and the ``vecnormalize.pkl``
beside it; :class:`SB3Policy` normalises observations the way training did and
predicts. Needs the ``[train]`` extra (torch, Stable-Baselines3).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.errors import PolicyError

__all__ = ["SB3Policy", "load_sb3"]


class SB3Policy:
    """A Stable-Baselines3 model, with the VecNormalize statistics it was trained with."""

    def __init__(self, model: Any, obs_rms: Any = None, clip_obs: float = 10.0, epsilon: float = 1e-8) -> None:
        self.model, self.obs_rms, self.clip_obs, self.epsilon = model, obs_rms, clip_obs, epsilon
        self.obs_size = int(model.observation_space.shape[0])
        self.action_size = int(model.action_space.shape[0])

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        if self.obs_rms is None:
            return obs
        norm = (obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + self.epsilon)
        return np.clip(norm, -self.clip_obs, self.clip_obs).astype(np.float32)

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:  # fmt: skip
        return self.model.predict(self.normalize(np.asarray(obs, dtype=np.float32)), deterministic=deterministic)


def load_sb3(path: str | Path) -> SB3Policy:
    """Load a PPO, SAC or TD3 model (a ``.zip``, or a folder with ``model.zip`` or ``best_model.zip``)
    and the ``vecnormalize.pkl`` beside it if present."""
    import pickle
    import zipfile

    from stable_baselines3 import PPO, SAC, TD3

    path = Path(path)
    zip_path = path
    if path.is_dir():
        zip_path = next((path / n for n in ("model.zip", "best_model.zip") if (path / n).exists()), path / "model.zip")
    if not zip_path.is_file():
        raise PolicyError(f"no model at {zip_path}")
    if not zipfile.is_zipfile(zip_path):
        raise PolicyError(f"{zip_path}: not a Stable-Baselines3 model (not a zip archive)")
    for algo in (PPO, SAC, TD3):
        try:
            model = algo.load(zip_path, device="cpu")
            break
        except (ValueError, KeyError, TypeError, AttributeError, zipfile.BadZipFile, RuntimeError):
            continue
    else:
        raise PolicyError(f"{zip_path} is not a PPO, SAC or TD3 model")
    obs_rms, clip_obs = None, 10.0
    stats = zip_path.parent / "vecnormalize.pkl"
    if stats.exists():
        try:
            with stats.open("rb") as fh:
                vec = pickle.load(fh)
            obs_rms, clip_obs = vec.obs_rms, vec.clip_obs
        except (pickle.UnpicklingError, EOFError, AttributeError) as exc:
            raise PolicyError(f"{stats}: unreadable normalisation statistics ({type(exc).__name__})") from None
    return SB3Policy(model, obs_rms, clip_obs)
