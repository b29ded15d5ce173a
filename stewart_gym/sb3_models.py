"""Stable-Baselines3 models with the observation normalisation they were trained with, and residual policies.

:func:`load_sb3` reads a PPO, SAC, TD3 or TQC model and the ``vecnormalize.pkl``
beside it; :class:`SB3Policy` normalises observations the way training did and
predicts. Needs the ``[train]`` extra (torch, Stable-Baselines3).

A *residual* policy learns a correction on top of a classical controller: the action sent is
``clip(base(obs) + scale · w · learned(obs), −1, 1)``, where the weight w may fade the correction out near
the target (``inner_mm``, ``fade_mm``) and keep it out once the ball has come in (``release_mm``), or has stayed
near it for ``dwell_s``. Training
wraps the env in :class:`ResidualAction` (the hyperparameter ``residual: {base: lqr, scale: 0.5}``);
:class:`ResidualPolicy` runs a trained one. The run's
``config.yaml`` records the base's gains or design as they were (``design``), so a later retune of the shipped
controller does not change a trained policy; the bundle records the base too, so deploy runs the same sum.

An *ensemble* folder (``stewart-gym ensemble``) holds several networks trained alike with different seeds
(``members/0``, ``members/1``, … each a run folder in miniature, listed in ``ensemble.json``:
:func:`~stewart_gym.outputs.ensemble_members`); :func:`load_learned`
reads one as an :class:`EnsemblePolicy`, which acts with the mean of its members' deterministic actions.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from stewart_gym.control import CLASSICAL, ResidualMix, checked_design, classical_controller, shipped_design
from stewart_gym.errors import ConfigError, PolicyError
from stewart_gym.outputs import ENSEMBLE_FILE, ensemble_members, model_statistics

__all__ = ["EnsemblePolicy", "ResidualAction", "ResidualPolicy", "SB3Policy", "check_residual", "deterministic_module",
           "load_learned", "load_sb3", "mean_module", "own_deterministic_pass", "residual_base", "residual_mix"]  # fmt: skip


class SB3Policy:
    """A Stable-Baselines3 model, with the VecNormalize statistics it was trained with.

    A deterministic :meth:`predict` of a PPO (without gSDE), SAC, TD3 or TQC model runs the model's deterministic
    action as one torch module (:func:`deterministic_module`) and clips or rescales it as SB3's ``predict`` does:
    the same numbers to the last bit, without the checks and conversions SB3's call makes each time. Any other
    model predicts through SB3's own ``predict``."""

    def __init__(self, model: Any, obs_rms: Any = None, clip_obs: float = 10.0, epsilon: float = 1e-8) -> None:
        self.model, self.obs_rms, self.clip_obs, self.epsilon = model, obs_rms, clip_obs, epsilon
        self.obs_size = int(model.observation_space.shape[0])
        self.action_size = int(model.action_space.shape[0])
        self._deterministic: Any = None  # the deterministic action's module, made at the first deterministic call
        #: whether a deterministic :meth:`predict` runs :func:`deterministic_module` (else SB3's own ``predict``)
        self.own_pass = own_deterministic_pass(model)

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_deterministic": None}  # (the module is made again where it is needed)

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        if self.obs_rms is None:
            return obs
        norm = (obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + self.epsilon)
        return np.clip(norm, -self.clip_obs, self.clip_obs).astype(np.float32)

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:  # fmt: skip
        """The action for ``obs`` (one observation, or a row each), normalised as in training; and None (no
        recurrent state)."""
        observation = np.asarray(obs, dtype=np.float32)
        if observation.shape[-1:] != (self.obs_size,) or observation.ndim > 2:
            raise ValueError(f"expected an observation of shape ({self.obs_size},) or rows of them, got an array of "
                             f"shape {observation.shape}")  # fmt: skip
        observation = self.normalize(observation)
        if not (deterministic and self.own_pass):
            return self.model.predict(observation, deterministic=deterministic)
        import torch

        policy = self.model.policy
        if self._deterministic is None:
            self._deterministic = deterministic_module(self.model).eval()
        with torch.no_grad():
            rows = torch.from_numpy(np.ascontiguousarray(observation.reshape(-1, self.obs_size)))
            actions = self._deterministic(rows).numpy().reshape(-1, self.action_size)
        space = policy.action_space  # as SB3's predict: squashed actions rescaled to the space, others clipped to it
        actions = policy.unscale_action(actions) if policy.squash_output else np.clip(actions, space.low, space.high)
        return (actions[0] if observation.ndim == 1 else actions), None


def _policy_module(zip_path: Path) -> str:
    """The module of the policy class saved in an SB3 model archive ("" if it cannot be read)."""
    import json
    import zipfile

    try:
        with zipfile.ZipFile(zip_path) as archive:
            data = json.loads(archive.read("data"))
        return str(data["policy_class"]["__module__"])
    except (KeyError, TypeError, ValueError, OSError, zipfile.BadZipFile):
        return ""


#: The algorithm of a saved model, by the module of its policy class (PPO's is the shared actor-critic one).
ALGO_OF_POLICY_MODULE = {"stable_baselines3.common.policies": "ppo", "stable_baselines3.sac.policies": "sac",
                         "stable_baselines3.td3.policies": "td3", "sb3_contrib.tqc.policies": "tqc"}


def saved_algo(zip_path: str | Path) -> str | None:
    """``"ppo"``, ``"sac"``, ``"td3"`` or ``"tqc"``: the algorithm a model archive was saved by (None if unknown)."""
    return ALGO_OF_POLICY_MODULE.get(_policy_module(Path(zip_path)))


def load_sb3(path: str | Path) -> SB3Policy:
    """Load a PPO, SAC, TD3 or TQC model (a ``.zip``, or a folder with ``model.zip`` or ``best_model.zip``)
    and the normalisation statistics saved with it, if any (:func:`~stewart_gym.outputs.model_statistics`:
    ``vecnormalize.pkl`` beside it, or a checkpoint's own)."""
    import pickle
    import zipfile

    from sb3_contrib import TQC
    from stable_baselines3 import PPO, SAC, TD3

    path = Path(path)
    zip_path = path
    if path.is_dir():
        zip_path = next((path / n for n in ("model.zip", "best_model.zip") if (path / n).exists()), path / "model.zip")
    if not zip_path.is_file():
        raise PolicyError(f"no model at {zip_path}")
    if not zipfile.is_zipfile(zip_path):
        raise PolicyError(f"{zip_path}: not a Stable-Baselines3 model (not a zip archive): give the model.zip that "
                          "stewart-gym train wrote, or its run folder")  # fmt: skip
    # SAC and TQC each load the other's model without complaint: the saved policy class says which it is
    order = (TQC, PPO, SAC, TD3) if _policy_module(zip_path).startswith("sb3_contrib.tqc") else (PPO, SAC, TD3, TQC)
    for algo in order:
        try:
            model = algo.load(zip_path, device="cpu")
            break
        except (ValueError, KeyError, TypeError, AttributeError, zipfile.BadZipFile, RuntimeError):
            continue
    else:
        raise PolicyError(f"{zip_path} is not a PPO, SAC, TD3 or TQC model that this Stable-Baselines3 can load: "
                          "give a model that stewart-gym train wrote, or train one")  # fmt: skip
    obs_rms, clip_obs = None, 10.0
    stats = model_statistics(zip_path)
    if stats is not None:
        try:
            with stats.open("rb") as fh:
                vec = pickle.load(fh)
            obs_rms, clip_obs = vec.obs_rms, vec.clip_obs
        except Exception as exc:  # noqa: BLE001 (a damaged pickle raises nearly anything)
            raise PolicyError(f"{stats}: unreadable normalisation statistics ({type(exc).__name__})") from None
    return SB3Policy(model, obs_rms, clip_obs)


class EnsemblePolicy:
    """Several networks trained alike (one recipe, different seeds) acting as one: the mean of their actions,
    each as its own :meth:`SB3Policy.predict` gives it (normalised with its own statistics, clipped to the bounds).
    Averaging cancels much of what each network got wrong by chance (docs: Control).

    The deterministic mean is one torch module (:attr:`module`, raw observation → mean action), the graph that
    ``export`` writes to ONNX, so evaluation and the bundle run the same computation.
    """

    def __init__(self, members: list[SB3Policy]) -> None:
        if len(members) < 1:
            raise PolicyError("an ensemble needs at least one network")
        sizes = {(m.obs_size, m.action_size) for m in members}
        if len(sizes) != 1:
            raise PolicyError(f"the ensemble's networks differ in (observation, action) size: {sorted(sizes)}")
        if any(m.obs_rms is None for m in members):
            raise PolicyError("an ensemble's networks must each have their vecnormalize.pkl (train with normalize)")
        self.members = members
        self.obs_size, self.action_size = sizes.pop()
        self.module = mean_module(members)

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:  # fmt: skip
        if not deterministic:  # each network's own sample, averaged
            actions = [m.predict(obs, deterministic=False)[0] for m in self.members]
            return np.mean(actions, axis=0, dtype=np.float64).astype(np.float32), None
        import torch

        x = np.asarray(obs, dtype=np.float32)
        with torch.no_grad():
            action = self.module(torch.as_tensor(x.reshape(-1, self.obs_size))).numpy()
        return action.reshape(*x.shape[:-1], self.action_size), None


def own_deterministic_pass(model: Any) -> bool:
    """Whether :func:`deterministic_module` gives ``model``'s deterministic action as SB3's ``predict`` does, on
    this process's CPU tensors: a PPO, SAC, TD3 or TQC on the CPU without gSDE (whose squashing of PPO's action the
    module leaves out)."""
    from sb3_contrib import TQC
    from stable_baselines3 import PPO, SAC, TD3

    return (isinstance(model, (PPO, SAC, TD3, TQC)) and not getattr(model, "use_sde", False)
            and not (isinstance(model, PPO) and model.policy.squash_output) and model.device.type == "cpu")


def deterministic_module(model: Any) -> Any:
    """A torch module: normalised observation → the deterministic action of SB3 ``model`` before clipping (PPO:
    the Gaussian's mean; SAC/TQC: the tanh-squashed mean; TD3: the actor's output), as SB3's export guide does."""
    import torch
    from sb3_contrib import TQC
    from stable_baselines3 import PPO, SAC

    class Deterministic(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.policy = model.policy if isinstance(model, PPO) else model.policy.actor

        def forward(self, obs: torch.Tensor) -> torch.Tensor:
            p = self.policy
            if isinstance(model, PPO):
                return p.action_net(p.mlp_extractor.forward_actor(p.extract_features(obs, p.pi_features_extractor)))
            if isinstance(model, (SAC, TQC)):  # the squashed Gaussian's mode, as predict(deterministic=True) gives it
                return torch.tanh(p.get_action_dist_params(obs)[0])
            return p(obs)

    return Deterministic()


def mean_module(members: list[SB3Policy]) -> Any:
    """A torch module (in eval mode): raw observation → the mean of the members' deterministic actions, each
    normalised and clipped as :meth:`SB3Policy.predict` does (float32 throughout)."""
    import torch

    space = members[0].model.action_space
    low = torch.as_tensor(space.low, dtype=torch.float32)
    high = torch.as_tensor(space.high, dtype=torch.float32)

    class Mean(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.nets = torch.nn.ModuleList(deterministic_module(m.model) for m in members)
            self.stats = [tuple(torch.as_tensor(np.asarray(v), dtype=torch.float32)
                                for v in (m.obs_rms.mean, np.sqrt(m.obs_rms.var + m.epsilon), m.clip_obs))
                          for m in members]  # fmt: skip

        def forward(self, obs: torch.Tensor) -> torch.Tensor:
            actions = []
            for net, (mean, std, clip) in zip(self.nets, self.stats):
                normalised = torch.minimum(torch.maximum((obs - mean) / std, -clip), clip)
                actions.append(torch.minimum(torch.maximum(net(normalised), low), high))
            return torch.stack(actions).mean(dim=0)

    return Mean().eval()


def load_learned(path: str | Path) -> SB3Policy | EnsemblePolicy:
    """An ensemble folder's :class:`EnsemblePolicy` (:data:`ENSEMBLE_FILE` in it), else :func:`load_sb3`."""
    path = Path(path)
    if path.is_dir() and (path / ENSEMBLE_FILE).is_file():
        return EnsemblePolicy([load_sb3(m) for m in ensemble_members(path)])
    return load_sb3(path)


#: The keys of a ``residual`` hyperparameter (:func:`check_residual`).
RESIDUAL_FIELDS = ("base", "scale", "fade_mm", "inner_mm", "release_mm", "dwell_s", "design")


def check_residual(spec: Any, recorded: bool = False) -> dict[str, Any]:
    """A ``residual`` hyperparameter, checked: ``{base: NAME, scale: s, fade_mm: f, inner_mm: r, release_mm: q,
    dwell_s: t, design: {...}}`` with 0 < s ≤ 2, f ≥ 0 and r ≥ 0 (within r of the target the base acts alone and
    over the next f mm the correction fades in: :func:`~stewart_gym.control.residual_action`; both 0, the
    default, never fades) and q 0 (the default) or more than r > 0 (once within r, the correction stays off until
    the ball is farther than q: :class:`~stewart_gym.control.ResidualMix`), and t 0 (the default) or, with that
    latch, the seconds within q after which it closes anyway. NAME is a shipped classical controller
    (:data:`~stewart_gym.control.CLASSICAL`: lqr, lqr-pid, pid, pid-kalman); ``design``, its gains or design,
    is the shipped one's with any fields that ``design`` gives replaced (all of them, or a few, e.g.
    ``{handover_dwell_s: 3}``); training records the whole design. ``recorded``: ``spec`` is what a run recorded,
    its design whole as the run trained with it, so a field the design has gained since (a lead, a dwell) is off,
    its default, not the shipped design's: a later retune of the shipped controller leaves the run as it was
    trained. (A recorded spec without a design, from before runs recorded it, still takes the shipped one.)"""
    if not isinstance(spec, dict) or set(spec) - set(RESIDUAL_FIELDS) or spec.get("base") not in CLASSICAL:
        raise ConfigError(f"residual must be {{base: {'|'.join(sorted(CLASSICAL))}, scale: S, fade_mm: F, inner_mm: R, "
                          f"release_mm: Q, dwell_s: T}}, got {spec!r}")  # fmt: skip
    scale = spec.get("scale", 0.5)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0 < scale <= 2:
        raise ConfigError(f"residual scale must be a number in (0, 2], got {scale!r}")
    for key in ("fade_mm", "inner_mm", "release_mm", "dwell_s"):
        value = spec.get(key, 0.0)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 1000:
            raise ConfigError(f"residual {key} must be a number in [0, 1000), got {value!r}")
    release, inner = float(spec.get("release_mm", 0.0)), float(spec.get("inner_mm", 0.0))
    dwell = float(spec.get("dwell_s", 0.0))
    try:  # the latch's own checks (release beyond inner, a dwell only with the latch), once
        ResidualMix(float(scale), (1.0, 1.0), float(spec.get("fade_mm", 0.0)), inner, release, dwell)
    except ValueError as exc:
        raise ConfigError(f"residual {exc}") from None
    kind = CLASSICAL[spec["base"]][0]
    try:
        changes = spec.get("design", {})
        if not isinstance(changes, dict):
            raise ValueError(f"design must be a mapping of the design's fields, got {changes!r}")
        whole = recorded and "design" in spec
        design = checked_design({**({} if whole else asdict(shipped_design(spec["base"]))), **changes}, kind)
    except ValueError as exc:
        raise ConfigError(f"residual design (the {spec['base']} base's): {exc}") from None
    checked = {"base": spec["base"], "scale": float(scale), "fade_mm": float(spec.get("fade_mm", 0.0)),
               "inner_mm": inner, "release_mm": release, "design": asdict(design)}  # fmt: skip
    if dwell > 0:  # recorded only when set: runs trained before the dwell existed read the same
        checked["dwell_s"] = dwell
    return checked


def residual_mix(spec: dict[str, Any], plate_half: tuple[float, float], dt: float = 0.02) -> ResidualMix:
    """How a checked residual ``spec`` adds its correction to its base's action on a plate of ``plate_half`` (m),
    every ``dt`` s."""
    return ResidualMix(spec["scale"], plate_half, spec["fade_mm"], spec["inner_mm"], spec["release_mm"],
                       spec.get("dwell_s", 0.0), dt)  # fmt: skip


def residual_base(spec: dict[str, Any], geometry: Any = "servo-hexapod", plate_half: tuple[float, float] | None = None,
                  dt: float = 0.02) -> Any:  # fmt: skip
    """The classical controller a checked residual ``spec`` adds to (its ``design``, for ``geometry``). Raises
    :class:`ConfigError` if the design does not fit the build (a dither of half its max tilt or more)."""
    kind = CLASSICAL[spec["base"]][0]
    try:
        return classical_controller(kind, checked_design(spec["design"], kind), geometry, dt, plate_half)
    except ValueError as exc:
        raise ConfigError(f"residual design (the {spec['base']} base's): {exc}") from None


class ResidualAction(gym.Wrapper):
    """Gymnasium wrapper (for training): the agent's action is a correction to a classical controller's.

    Sends the :class:`~stewart_gym.control.ResidualMix` of the base's action and the agent's, for the
    observation the agent acted on; resets the base's and the mix's state with each episode. A hyperparameter
    file names it as RL Zoo's ``env_wrapper`` (``{stewart_gym.sb3_models.ResidualAction: {residual: {…}}}``), so
    that ``stewart-gym train`` and ``python -m rl_zoo3.train`` build the same wrapper from it.
    """

    def __init__(self, env: gym.Env, residual: dict[str, Any]) -> None:
        super().__init__(env)
        spec = check_residual(residual)
        u = env.unwrapped
        self.mix = residual_mix(spec, u.plate_half_extent, 1.0 / u.sim.control_hz)
        self.base = residual_base(spec, u.sim.geometry, u.plate_half_extent, 1.0 / u.sim.control_hz)
        self._obs: np.ndarray | None = None

    def reset(self, **kwargs: Any) -> Any:
        obs, info = self.env.reset(**kwargs)
        self.base.reset()
        self.mix.reset()
        self._obs = obs
        return obs, info

    def step(self, action: Any) -> Any:
        if self._obs is None:
            raise RuntimeError("call reset before step")
        total = self.mix(self.base(self._obs), action, self._obs)
        obs, reward, terminated, truncated, info = self.env.step(total)
        self._obs = obs
        return obs, reward, terminated, truncated, info


class ResidualPolicy:
    """A trained residual policy: the :class:`~stewart_gym.control.ResidualMix` of its base and its network."""

    def __init__(self, learned: SB3Policy | EnsemblePolicy, base: Any, mix: ResidualMix) -> None:
        self.learned, self.base, self.mix = learned, base, mix
        self.obs_size, self.action_size = learned.obs_size, learned.action_size

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:  # fmt: skip
        if episode_start is not None and np.any(episode_start):
            self.mix.reset()
        base, _ = self.base.predict(obs, episode_start=episode_start)
        correction, _ = self.learned.predict(obs, deterministic=deterministic)
        return self.mix(base, correction, obs), None
