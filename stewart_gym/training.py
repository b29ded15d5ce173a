"""Train Stable-Baselines3 agents (PPO, SAC, TD3, and sb3-contrib's TQC) on the registered environments.

Hyperparameters live in RL-Zoo-style YAML files, one section per env id
(``stewart_gym/hyperparams/<algo>.yml``): ``n_envs``, ``n_timesteps``, ``normalize``,
``policy``, ``policy_kwargs``, ``env_kwargs`` and the algorithm's own keywords.

A run folder holds ``config.yaml`` (the hyperparameters and options used),
``git.txt`` (revision), ``model.zip`` + ``vecnormalize.pkl`` (final),
``best/`` (best by evaluation, with its statistics), ``checkpoints/``,
``tb/`` (TensorBoard), ``eval.csv`` (learning curve: timesteps, the wall time the snapshot was taken at,
mean reward, success rate, the wall time its evaluation came back at) and ``metrics.json``.
"""

from __future__ import annotations

import copy
import csv
import inspect
import io
import json
import math
import os
import pickle
import subprocess
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from sb3_contrib import TQC
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure as make_sb3_logger
from stable_baselines3.common.noise import ActionNoise, NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecNormalize

from stewart_gym.errors import ConfigError, TrainingDiverged
from stewart_gym.inputs import read_yaml
from stewart_gym.outputs import ENSEMBLE_FILE, RUN_GEOMETRY_FILE, model_statistics, run_config
from stewart_gym.presets import PRESETS
from stewart_gym.sb3_models import ResidualAction, check_residual, residual_base, saved_algo
from stewart_gym.training_evals import BackgroundEvaluator, Evaluation, InProcessEvaluator, worker_start_method

__all__ = ["ALGOS", "EVALUATION_SECTION", "NOISE_TYPES", "RESIDUAL_WRAPPER", "RUN_FILES", "RUN_KEYS", "TrainConfig",
           "algo_keywords", "check_action_noise", "check_algo_keywords", "check_hyperparameter_values",
           "check_resumed_observer", "check_algo_values", "check_recipe", "check_run_dir", "check_run_env",
           "action_noise", "evaluation_env", "load_hyperparams", "make_env", "planned_timesteps", "rollout_note",
           "run_hyperparams", "train", "whole_rollouts_note", "InProcessVecEnv", "VEC_ENVS", "check_vec_env"]

ALGOS: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "sac": SAC, "td3": TD3, "tqc": TQC}
HYPERPARAM_DIR = Path(__file__).resolve().parent / "hyperparams"  # package data: works after a non-editable install
#: The keys of a loaded section that set up the run rather than the algorithm: RL Zoo's own, and the evaluation
#: settings and residual spec that :func:`load_hyperparams` brings in from where RL Zoo keeps them apart.
RUN_KEYS = ("n_envs", "n_timesteps", "normalize", "policy", "env_kwargs", "eval_freq", "eval_episodes", "residual",
            "noise_type", "noise_std")
#: The ``env_wrapper`` (RL Zoo's key) that makes a recipe residual: ``{RESIDUAL_WRAPPER: {residual: {base, …}}}``.
RESIDUAL_WRAPPER = "stewart_gym.sb3_models.ResidualAction"
#: The file-level section, by env id, of the evaluations during training (``eval_freq``, ``eval_episodes``). RL Zoo
#: reads only the env ids' sections and takes its own evaluation settings from ``--eval-freq``/``--eval-episodes``.
EVALUATION_SECTION = "evaluation"
#: The evaluations during training draw their episodes from seed ``seed + EVAL_SEED_OFFSET``: apart from the
#: training envs' (``seed`` … ``seed + n_envs - 1``), and the same in each run of a seed.
EVAL_SEED_OFFSET = 10_000
#: RL-Zoo's ``noise_type``: Gaussian or Ornstein-Uhlenbeck exploration noise on the actions of SAC, TD3 or TQC
NOISE_TYPES = ("normal", "ornstein-uhlenbeck")


@dataclass
class TrainConfig:
    """Options of one training run (besides the YAML hyperparameters)."""

    env_id: str = "StewartBallBalance-v0"
    algo: str = "ppo"
    hyperparams: str | None = None  # YAML file; default stewart_gym/hyperparams/<algo>.yml
    run_dir: str = "runs/latest"
    geometry: str | None = None  # preset or TOML path: overrides the YAML's env_kwargs geometry
    backend: str | None = None  # physics engine ("pybullet" or "mujoco"): overrides the YAML's env_kwargs backend
    estimator: str | None = None  # "lowpass" or "kalman": overrides the YAML's env_kwargs estimator
    sensor: str | None = None  # "panel", "camera" (any preset per episode) or a camera preset: overrides the YAML's
    seed: int = 0
    n_timesteps: int | None = None  # overrides the YAML
    n_envs: int | None = None  # overrides the YAML
    vec_env: str = "dummy"  # where the n_envs copies step: "dummy" (this process) or "subproc" (one process each)
    eval_freq: int | None = None  # env steps between evaluations (total over all envs)
    eval_episodes: int | None = None
    background_eval: bool | None = None  # evaluate in a second process (default: where there are 2 cores or more)
    checkpoint_freq: int = 100_000
    resume: str | None = None  # a run folder or checkpoint .zip to continue from
    twin: str | None = None  # a twin file: train for that platform (randomised narrowly around it)
    overrides: dict[str, Any] | None = None  # replace the YAML's hyperparameters (env_kwargs: key by key)
    progress_bar: bool = True
    tensorboard: bool = True
    verbose: int = 0


class FixedStatistics(RunningMeanStd):
    """Observation statistics that no longer update: a resumed run scales its inputs as the policy it resumes
    was trained with. Updating them on another platform (a fine-tune for a twin) shifts every input the
    policy sees before it has learnt anything there, and can undo it. It pickles as SB3's own
    ``RunningMeanStd``, so the statistics a resumed run saves load anywhere."""

    @classmethod
    def of(cls, stats: RunningMeanStd) -> FixedStatistics:
        fixed = cls(shape=stats.mean.shape)
        fixed.mean, fixed.var, fixed.count = stats.mean.copy(), stats.var.copy(), stats.count
        return fixed

    def update(self, arr: np.ndarray) -> None:
        return None

    def __reduce__(self) -> tuple[Any, ...]:
        return RunningMeanStd, (), dict(self.__dict__)


def resume_statistics(resume: Path) -> Path | None:
    """The VecNormalize statistics of a model to resume: ``vecnormalize.pkl`` in a run folder or beside a model
    (``best/best_model.zip``), ``model_vecnormalize_<n>_steps.pkl`` beside a checkpoint; None if there are none."""
    return model_statistics(resume / "model.zip" if resume.is_dir() else resume)


def shipped_recipes() -> list[str]:
    """The names of the hyperparameter files that ship with the package (``ppo``, ``ppo_residual``, …)."""
    return sorted(p.stem for p in HYPERPARAM_DIR.glob("*.yml"))


def hyperparams_path(spec: str | Path) -> Path:
    """A YAML file's path, or a shipped recipe's name (``ppo_residual``: wherever the package is installed)."""
    path = Path(spec)
    if path.exists() or path.suffix:
        return path
    if str(spec) in shipped_recipes():
        return HYPERPARAM_DIR / f"{spec}.yml"
    raise ConfigError(f"--hyperparams {spec}: neither a file nor a shipped recipe ({', '.join(shipped_recipes())})")


def load_hyperparams(algo: str, env_id: str, path: str | Path | None = None) -> dict[str, Any]:
    """The YAML section for ``env_id`` (a copy), as RL Zoo reads it, with this package's own settings brought in:
    the residual spec from its ``env_wrapper`` (``residual``) and ``eval_freq``/``eval_episodes`` from the
    :data:`EVALUATION_SECTION`. Raises :class:`ConfigError` naming the file and what is wrong.
    ``path``: a YAML file or a shipped recipe's name (:func:`hyperparams_path`); default the algorithm's own."""
    path = hyperparams_path(path) if path else HYPERPARAM_DIR / f"{algo}.yml"
    data = read_yaml(path, "hyperparameter file") or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of env ids to hyperparameter sections, got "
                          f"{type(data).__name__}")  # fmt: skip
    if env_id not in data:
        sections = sorted(str(k) for k in data if k != EVALUATION_SECTION)
        raise ConfigError(f"{path} has no section for {env_id!r} (sections: {sections})")
    if not isinstance(data[env_id], dict):
        raise ConfigError(f"{path}: the section {env_id!r} must be a mapping of hyperparameters (key: value), got "
                          f"{data[env_id]!r}")  # fmt: skip
    hp = dict(data[env_id])
    for key in ("eval_freq", "eval_episodes", "residual"):
        if key in hp:
            where = (f"the file's {EVALUATION_SECTION}: section ({EVALUATION_SECTION}: {{{env_id}: {{{key}: …}}}})"
                     if key != "residual" else f"env_wrapper: {{{RESIDUAL_WRAPPER}: {{residual: …}}}}")
            raise ConfigError(f"{path}: {env_id}.{key}: RL Zoo would pass it to the algorithm; write it as {where}")
    if "env_wrapper" in hp:
        where = f"{path}: {env_id}.env_wrapper"
        hp["residual"] = _residual_from_wrapper(hp.pop("env_wrapper"), where)
        try:  # its values too, naming the file (training checks the spec again as it starts)
            check_residual(hp["residual"])
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    hp.update(_evaluation_settings(data.get(EVALUATION_SECTION), env_id, path))
    _check_env_kwargs(hp.get("env_kwargs"), env_id, f"{path}: {env_id}.env_kwargs")
    for key in ("n_envs", "n_timesteps", "eval_freq", "eval_episodes"):
        if key in hp and (isinstance(hp[key], bool) or not isinstance(hp[key], (int, float)) or not hp[key] >= 1):
            raise ConfigError(f"{path}: {env_id}.{key} must be a number ≥ 1, got {hp[key]!r}")
    return hp


def _check_env_kwargs(env_kwargs: Any, env_id: str, where: str) -> None:
    """A recipe's ``env_kwargs``: a mapping of keywords that ``gym.make(env_id, ...)`` takes; :class:`ConfigError`
    naming ``where`` otherwise (their values are the env's to check)."""
    if env_kwargs is None:
        return
    if not isinstance(env_kwargs, dict):
        raise ConfigError(f"{where} must be a mapping of the env's keywords (backend: batched, …), got {env_kwargs!r}")
    from stewart_gym.envs import ENV_IDS, make_keywords

    if env_id not in ENV_IDS:  # not one of ours: the env says what it takes
        return
    if "workers" in env_kwargs:  # a keyword of gym.make_vec's batched vector env, not of training
        raise ConfigError(f"{where}: workers: training steps its batched copies in one process; leave workers out "
                          "(gym.make_vec(..., workers=k) splits copies over processes outside training)")  # fmt: skip
    known = make_keywords(env_id)
    unknown = sorted(str(key) for key in env_kwargs if key not in known)
    if unknown:
        raise ConfigError(f"{where}: {env_id} takes no keyword {unknown[0]!r}; it takes {', '.join(sorted(known))}")


def _residual_from_wrapper(wrapper: Any, where: str) -> dict[str, Any]:
    """The residual spec of an ``env_wrapper`` entry: ``{RESIDUAL_WRAPPER: {residual: {...}}}`` (or a list of
    that one entry), the only wrapper a recipe may name."""
    entry = wrapper[0] if isinstance(wrapper, list) and len(wrapper) == 1 else wrapper
    if (not isinstance(entry, dict) or list(entry) != [RESIDUAL_WRAPPER] or not isinstance(entry[RESIDUAL_WRAPPER], dict)
            or list(entry[RESIDUAL_WRAPPER]) != ["residual"] or not isinstance(entry[RESIDUAL_WRAPPER]["residual"], dict)):
        raise ConfigError(f"{where}: the one wrapper a recipe may name is {{{RESIDUAL_WRAPPER}: {{residual: {{base: …, "
                          f"scale: …}}}}}}, got {wrapper!r}")  # fmt: skip
    return dict(entry[RESIDUAL_WRAPPER]["residual"])


def _evaluation_settings(section: Any, env_id: str, path: Path) -> dict[str, Any]:
    """``eval_freq``/``eval_episodes`` for ``env_id`` from the file's :data:`EVALUATION_SECTION` (none if absent)."""
    if section is None:
        return {}
    if not isinstance(section, dict) or not all(isinstance(v, dict) for v in section.values()):
        raise ConfigError(f"{path}: {EVALUATION_SECTION} must map env ids to {{eval_freq: …, eval_episodes: …}}, got "
                          f"{section!r}")  # fmt: skip
    settings = dict(section.get(env_id) or {})
    unknown = sorted(set(settings) - {"eval_freq", "eval_episodes"})
    if unknown:
        raise ConfigError(f"{path}: {EVALUATION_SECTION}.{env_id}: unknown keys {unknown} (eval_freq, eval_episodes)")
    return settings


def run_hyperparams(config: TrainConfig) -> dict[str, Any]:
    """The YAML section of ``config`` with its ``overrides`` applied (``env_kwargs`` merged key by key). A resumed
    run without ``--hyperparams`` continues with its own recipe (:func:`resumed_hyperparams`), where it has one."""
    hp = resumed_hyperparams(config) if config.resume and config.hyperparams is None else None
    if hp is None:
        hp = load_hyperparams(config.algo, config.env_id, config.hyperparams)
    for key, value in (config.overrides or {}).items():
        if key == "env_kwargs":
            hp["env_kwargs"] = {**(hp.get("env_kwargs") or {}), **value}
        else:
            hp[key] = value
    return hp


def resumed_hyperparams(config: TrainConfig) -> dict[str, Any] | None:
    """The hyperparameters the run ``config.resume`` trained with (its ``config.yaml``: its recipe, its env's
    keywords, its residual), where it trained the same env with the same algorithm; else None. Its geometry file
    comes back as the run's own copy."""
    resume = Path(config.resume)
    model = resume / "model.zip" if resume.is_dir() else resume
    try:
        recorded = run_config(model)
    except (ValueError, ImportError) as exc:
        raise ConfigError(f"--resume {config.resume}: {exc}") from None
    if not isinstance(recorded, dict):
        return None
    options, hp = recorded.get("options") or {}, recorded.get("hyperparams")
    if not isinstance(hp, dict) or options.get("env_id") != config.env_id or options.get("algo") != config.algo:
        return None
    hp = copy.deepcopy(hp)
    for key in ("n_envs", "eval_freq", "eval_episodes"):  # the run's own command line had them apart
        if isinstance(options.get(key), int) and not isinstance(options[key], bool):
            hp[key] = options[key]
    _check_env_kwargs(hp.get("env_kwargs"), config.env_id, f"{recipe_name(config, resumed=True)}: env_kwargs")
    return hp


def recipe_name(config: TrainConfig, resumed: bool | None = None) -> str:
    """Where a run's hyperparameters come from, for its messages: ``--hyperparams``, the resumed run's
    ``config.yaml`` (``resumed``: whether :func:`resumed_hyperparams` gives them; None: find out) or the algorithm's
    own file."""
    if config.hyperparams:
        return str(config.hyperparams)
    if config.resume and (resumed if resumed is not None else resumed_hyperparams(config) is not None):
        return str(_run_folder(Path(config.resume)) / "config.yaml")
    return f"{config.algo}.yml"


def resume_note(config: TrainConfig) -> str | None:
    """What a resumed run without ``--hyperparams`` trains with, in a line; None where nothing is resumed or a
    recipe is given."""
    if not config.resume or config.hyperparams:
        return None
    if resumed_hyperparams(config) is not None:
        return f"--resume {config.resume}: its own recipe goes on ({recipe_name(config, resumed=True)}); " \
               "--hyperparams gives another"
    return f"--resume {config.resume}: no recipe of its own for {config.env_id} with {config.algo.upper()} " \
           f"(its config.yaml is missing or is another env's): {config.algo}.yml's; --hyperparams gives another"


#: The build a hyperparameter file's distances are written for when its ``env_kwargs`` name no ``geometry``.
RECIPE_GEOMETRY = "servo-hexapod"


def env_settings_source(config: TrainConfig) -> str:
    """Where a run's env keywords come from, for an error about them: the recipe's ``env_kwargs`` (its file and
    section, or the resumed run's ``config.yaml``) and the options that replace some of them."""
    if config.resume and config.hyperparams is None and resumed_hyperparams(config) is not None:
        recipe = f"{config.resume} (its config.yaml)"
    else:
        path = hyperparams_path(config.hyperparams) if config.hyperparams else HYPERPARAM_DIR / f"{config.algo}.yml"
        recipe = f"{path}: {config.env_id}.env_kwargs"
    options = [f"--{name} {value}" for name in ("geometry", "backend", "sensor", "estimator", "twin")
               if (value := getattr(config, name)) is not None]  # fmt: skip
    if (config.overrides or {}).get("env_kwargs"):
        options.append("the run's env_kwargs overrides")
    return recipe + (f" with {', '.join(options)}" if options else "")


def run_env_kwargs(config: TrainConfig, hp: dict[str, Any]) -> tuple[dict[str, Any], str | None]:
    """The YAML's ``env_kwargs`` on the build the run trains on (``--geometry``, else the YAML's), and a note of what
    that changed, or None.

    A recipe's ``start_distance`` (m) is written for its own build: its ``geometry``, else
    :data:`RECIPE_GEOMETRY`. On another build it is scaled by the ratio of the two builds' settling-test starts
    (:func:`~stewart_gym.envs.ball_env.settling_start`: 100 mm on the 300 mm plate, 67 mm on a 200 mm one) and
    rounded to 0.1 mm, so that the training episodes start as far out, for that plate, as the recipe meant.
    """
    from stewart_gym.envs.ball_env import settling_start
    from stewart_gym.presets import load_geometry

    env_kwargs = dict(hp.get("env_kwargs") or {})
    recipe_build = env_kwargs.get("geometry", RECIPE_GEOMETRY)
    if config.geometry is None:
        return env_kwargs, None
    env_kwargs["geometry"] = config.geometry
    start = env_kwargs.get("start_distance")
    if start is None:
        return env_kwargs, None
    offsets = [settling_start([v / 2 for v in load_geometry(g).plate_extent])
               for g in (recipe_build, config.geometry)]  # fmt: skip
    try:
        scaled = [round(float(v) * offsets[1] / offsets[0], 4) for v in start]
    except (TypeError, ValueError):  # not numbers: the env refuses it in one line
        return env_kwargs, None
    if scaled == [float(v) for v in start]:  # the same start on both plates (to 0.1 mm): left as written
        return env_kwargs, None
    env_kwargs["start_distance"] = scaled
    return env_kwargs, (f"start_distance scaled to {config.geometry}'s plate: {scaled} m (the recipe's {list(start)} "
                        f"m is for {recipe_build}; settling tests start {offsets[1] * 1e3:.0f} mm out here, "
                        f"{offsets[0] * 1e3:.0f} mm there)")  # fmt: skip


#: Constructor keywords that :func:`train` sets itself (from the run's options, or ``noise_type``/``noise_std``).
SET_BY_TRAIN = frozenset({"self", "policy", "env", "seed", "device", "tensorboard_log", "verbose", "_init_setup_model",
                          "action_noise"})  # fmt: skip


def algo_keywords(algo: str) -> set[str]:
    """The keywords of ``algo``'s constructor that a hyperparameter file may set (its own, not :data:`RUN_KEYS`)."""
    return set(inspect.signature(ALGOS[algo].__init__).parameters) - SET_BY_TRAIN


def check_algo_keywords(algo: str, hp: dict[str, Any], where: str | None = None) -> None:
    """Every key of a hyperparameter section is an RL-Zoo key or a keyword of ``algo`` (raises
    :class:`ConfigError` naming the others, and ``where`` they come from: most often a file written for another
    algorithm)."""
    ours = sorted((set(hp) - set(RUN_KEYS)) & (SET_BY_TRAIN - {"self", "_init_setup_model"}))
    if ours:
        raise ConfigError(f"{where + ': ' if where else ''}{ours} {'is' if len(ours) == 1 else 'are'} set by train "
                          "itself (device: the CPU; seed: --seed; action_noise: noise_type and noise_std; env, "
                          "tensorboard_log, verbose: the run's options); leave it out")  # fmt: skip
    unknown = sorted(set(hp) - set(RUN_KEYS) - algo_keywords(algo))
    if unknown:
        raise ConfigError(f"{where + ': ' if where else ''}{unknown} are not {algo.upper()} hyperparameters (a file "
                          f"for another algorithm? stewart_gym/hyperparams/{algo}.yml is {algo.upper()}'s)")


def _is_number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def _is_whole(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, int)


def _is_auto(v: Any) -> bool:
    """SAC's and TQC's learned entropy coefficient: ``auto``, or ``auto_`` and its positive start value."""
    if not isinstance(v, str) or not v.startswith("auto"):
        return False
    if v == "auto":
        return True
    try:
        return v.startswith("auto_") and math.isfinite(float(v[5:])) and float(v[5:]) > 0
    except ValueError:
        return False


#: ``normalize``'s keywords (VecNormalize's) that a recipe may give, and what each must be.
NORMALIZE_RULES: dict[str, tuple[Callable[[Any], bool], str]] = {
    "norm_obs": (lambda v: isinstance(v, bool), "true or false"),
    "norm_reward": (lambda v: isinstance(v, bool), "true or false"),
    "clip_obs": (lambda v: _is_number(v) and v > 0, "a positive number"),
    "clip_reward": (lambda v: _is_number(v) and v > 0, "a positive number"),
    "gamma": (lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]"),
    "epsilon": (lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]"),
}
#: ``policy_kwargs.activation_fn``: the names a recipe may give, and the torch module each stands for.
ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU", "silu": "SiLU", "gelu": "GELU"}
#: The ``policy_kwargs`` a recipe may give beside ``net_arch`` and ``log_std_init``: the algorithms that take
#: each, and what it must be.
POLICY_KWARG_RULES: dict[str, tuple[tuple[str, ...], Callable[[Any], bool], str]] = {
    "activation_fn": (("ppo", "sac", "td3", "tqc"), lambda v: isinstance(v, str) and v in ACTIVATIONS,
                      f"one of {', '.join(ACTIVATIONS)}"),
    "ortho_init": (("ppo",), lambda v: isinstance(v, bool), "true or false"),
    "n_critics": (("sac", "td3", "tqc"), lambda v: _is_whole(v) and 1 <= v <= 10, "a whole number from 1 to 10"),
    "n_quantiles": (("tqc",), lambda v: _is_whole(v) and 1 <= v <= 100, "a whole number from 1 to 100"),
}


#: What each common constructor keyword of the algorithms must be: (test, what to give). Checked before any
#: training or Ray starts (:func:`check_hyperparameter_values`), so a mistake is one line, not a traceback 25 s in.
VALUE_RULES: dict[str, tuple[Callable[[Any], bool], str]] = {
    "n_envs": (lambda v: _is_whole(v) and 1 <= v <= 1_000_000, "a whole number from 1 to 1,000,000"),
    "n_timesteps": (lambda v: _is_whole(v) and 1 <= v <= 1_000_000_000, "a whole number from 1 to 1e9"),
    "eval_freq": (lambda v: _is_whole(v) and 1 <= v <= 1_000_000_000, "a whole number from 1 to 1e9"),
    "eval_episodes": (lambda v: _is_whole(v) and 1 <= v <= 10_000, "a whole number from 1 to 10,000"),
    "target_update_interval": (lambda v: _is_whole(v) and v >= 1, "a whole number ≥ 1"),
    "use_sde_at_warmup": (lambda v: isinstance(v, bool), "true or false"),
    "optimize_memory_usage": (lambda v: v is False, "false (the replay buffer keeps time-limit endings apart)"),
    "rollout_buffer_class": (lambda v: v is None or v == {}, "left out: the algorithm's own buffer serves"),
    "rollout_buffer_kwargs": (lambda v: v is None or v == {}, "left out: the algorithm's own buffer serves"),
    "replay_buffer_class": (lambda v: v is None or v == {}, "left out: the algorithm's own buffer serves"),
    "replay_buffer_kwargs": (lambda v: v is None or v == {}, "left out: the algorithm's own buffer serves"),
    "learning_rate": (lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]"),
    "batch_size": (lambda v: _is_whole(v) and 1 <= v <= 10_000_000, "a whole number ≥ 1"),
    "n_steps": (lambda v: _is_whole(v) and 1 <= v <= 10_000_000, "a whole number ≥ 1"),
    "n_epochs": (lambda v: _is_whole(v) and 1 <= v <= 10_000, "a whole number ≥ 1"),
    "gamma": (lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]"),
    "gae_lambda": (lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]"),
    "clip_range": (lambda v: _is_number(v) and 0 < v <= 10, "a positive number"),
    "clip_range_vf": (lambda v: v is None or (_is_number(v) and v > 0), "a positive number or null"),
    "ent_coef": (lambda v: (_is_number(v) and v >= 0) or _is_auto(v),
                 "a number ≥ 0 (or, for SAC and TQC, 'auto' or 'auto_' and a positive start value, as auto_0.1)"),
    "target_entropy": (lambda v: v == "auto" or _is_number(v), "a number or 'auto'"),
    "vf_coef": (lambda v: _is_number(v) and v >= 0, "a number ≥ 0"),
    "max_grad_norm": (lambda v: _is_number(v) and v > 0, "a positive number"),
    "target_kl": (lambda v: v is None or (_is_number(v) and v > 0), "a positive number or null"),
    "buffer_size": (lambda v: _is_whole(v) and 1 <= v <= 100_000_000, "a whole number ≥ 1"),
    "learning_starts": (lambda v: _is_whole(v) and 0 <= v <= 100_000_000, "a whole number ≥ 0"),
    "tau": (lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]"),
    "train_freq": (lambda v: (_is_whole(v) and v >= 1) or (isinstance(v, (list, tuple)) and len(v) == 2
                                                           and _is_whole(v[0]) and v[0] >= 1
                                                           and v[1] in ("step", "episode")),
                   "a whole number ≥ 1, or [n, 'step' | 'episode']"),
    "gradient_steps": (lambda v: _is_whole(v) and (v >= 1 or v == -1), "a whole number ≥ 1, or -1"),
    "policy_delay": (lambda v: _is_whole(v) and v >= 1, "a whole number ≥ 1"),
    "target_policy_noise": (lambda v: _is_number(v) and v >= 0, "a number ≥ 0"),
    "target_noise_clip": (lambda v: _is_number(v) and v >= 0, "a number ≥ 0"),
    "top_quantiles_to_drop_per_net": (lambda v: _is_whole(v) and v >= 0, "a whole number ≥ 0"),
    "use_sde": (lambda v: isinstance(v, bool), "true or false"),
    "sde_sample_freq": (lambda v: _is_whole(v) and v >= -1, "a whole number ≥ -1"),
    "normalize_advantage": (lambda v: isinstance(v, bool), "true or false"),
    "normalize": (lambda v: isinstance(v, (bool, dict)), "true, false or a mapping of VecNormalize keywords "
                  f"({', '.join(NORMALIZE_RULES)})"),
    "policy": (lambda v: v in ("MlpPolicy", "MultiInputPolicy"), "MlpPolicy"),
    "env_kwargs": (lambda v: isinstance(v, dict), "a mapping of env keywords"),
}


def _check_net_arch(arch: Any) -> bool:
    def layers(v: Any) -> bool:
        return isinstance(v, list) and all(_is_whole(n) and 1 <= n <= 100_000 for n in v)

    if isinstance(arch, dict):
        return bool(arch) and set(arch) <= {"pi", "vf", "qf"} and all(layers(v) for v in arch.values())
    return layers(arch)


def check_hyperparameter_values(hp: dict[str, Any], where: str = "hyperparameters") -> None:
    """Each value of a hyperparameter section that the algorithm's constructor would trip on, checked first
    (:data:`VALUE_RULES`; ``policy_kwargs``: ``net_arch`` layer sizes ≥ 1, ``log_std_init`` finite). Raises
    :class:`ConfigError` naming ``where``, the key and what it must be."""
    for key, value in hp.items():
        rule = VALUE_RULES.get(key)
        if rule is not None and not rule[0](value):
            raise ConfigError(f"{where}: {key} must be {rule[1]}, got {value!r}")
    for key, value in (hp["normalize"] if isinstance(hp.get("normalize"), dict) else {}).items():
        rule = NORMALIZE_RULES.get(key)
        if rule is None:
            raise ConfigError(f"{where}: normalize.{key} is not a VecNormalize setting here; give "
                              f"{', '.join(NORMALIZE_RULES)}")  # fmt: skip
        if not rule[0](value):
            raise ConfigError(f"{where}: normalize.{key} must be {rule[1]}, got {value!r}")
    kwargs = hp.get("policy_kwargs")
    if kwargs is None:
        return
    if not isinstance(kwargs, dict):
        raise ConfigError(f"{where}: policy_kwargs must be a mapping (net_arch, log_std_init, …), got {kwargs!r}")
    if "net_arch" in kwargs and not _check_net_arch(kwargs["net_arch"]):
        raise ConfigError(f"{where}: policy_kwargs.net_arch must be a list of layer sizes ≥ 1 (or pi/vf/qf lists), "
                          f"got {kwargs['net_arch']!r}")  # fmt: skip
    if "log_std_init" in kwargs and not (_is_number(kwargs["log_std_init"]) and abs(kwargs["log_std_init"]) <= 20):
        raise ConfigError(f"{where}: policy_kwargs.log_std_init must be a number in [-20, 20], got "
                          f"{kwargs['log_std_init']!r}")  # fmt: skip


def check_action_noise(algo: str, hp: dict[str, Any]) -> None:
    """RL-Zoo's ``noise_type`` and ``noise_std`` (std of the noise, in action units, 0–1) are given together, to
    an off-policy algorithm. Without them TD3 explores only through its first ``learning_starts`` random steps
    (Stable-Baselines3 adds no action noise by default)."""
    if "noise_type" not in hp and "noise_std" not in hp:
        return
    if not issubclass(ALGOS[algo], OffPolicyAlgorithm):
        off_policy = ", ".join(sorted(k for k, v in ALGOS.items() if issubclass(v, OffPolicyAlgorithm)))
        raise ConfigError(f"noise_type/noise_std: action noise is for {off_policy}; {algo.upper()} explores through "
                          "its policy's own standard deviation (policy_kwargs.log_std_init)")
    kind, std = hp.get("noise_type"), hp.get("noise_std")
    if kind not in NOISE_TYPES:
        raise ConfigError(f"noise_type must be one of {list(NOISE_TYPES)} (with noise_std), got {kind!r}")
    if isinstance(std, bool) or not isinstance(std, (int, float)) or not 0 < std <= 1:
        raise ConfigError(f"noise_std must be a number in (0, 1] (the noise's std in action units), got {std!r}")


def _ppo_setting(hp: dict[str, Any], key: str) -> Any:
    """A PPO keyword as the run gives it: the recipe's, else Stable-Baselines3's default."""
    return hp[key] if key in hp else inspect.signature(PPO.__init__).parameters[key].default


def check_algo_values(algo: str, hp: dict[str, Any], n_envs: int, where: str = "hyperparameters") -> None:
    """The values of a recipe that hold for one algorithm only (raises :class:`ConfigError`): the
    ``policy_kwargs`` it takes (:data:`POLICY_KWARG_RULES`), a learned entropy coefficient for SAC and TQC only,
    and PPO's rollout (``n_steps`` per copy × ``n_envs``) and minibatch, which hold 2 or more samples each where
    ``normalize_advantage`` is on (the default)."""
    kwargs = hp.get("policy_kwargs") if isinstance(hp.get("policy_kwargs"), dict) else {}
    for key, value in kwargs.items():
        if key in ("net_arch", "log_std_init"):
            continue
        algos, test, what = POLICY_KWARG_RULES.get(key, ((), None, ""))
        if algo not in algos:
            takes = ["net_arch", "log_std_init", *(k for k, r in POLICY_KWARG_RULES.items() if algo in r[0])]
            raise ConfigError(f"{where}: policy_kwargs.{key} is not taken for {algo.upper()}; it takes "
                              f"{', '.join(takes)}")  # fmt: skip
        if not test(value):
            raise ConfigError(f"{where}: policy_kwargs.{key} must be {what}, got {value!r}")
    quantiles, dropped = kwargs.get("n_quantiles", 25), hp.get("top_quantiles_to_drop_per_net", 2)  # TQC's defaults
    if algo == "tqc" and dropped >= quantiles:
        raise ConfigError(f"{where}: top_quantiles_to_drop_per_net ({dropped}) must be below policy_kwargs.n_quantiles "
                          f"({quantiles})")  # fmt: skip
    if algo == "ppo" and isinstance(hp.get("ent_coef"), str):
        raise ConfigError(f"{where}: ent_coef {hp['ent_coef']!r}: a learned entropy coefficient is SAC's and TQC's; "
                          f"{algo.upper()} takes a number ≥ 0")  # fmt: skip
    if algo != "ppo" or not _ppo_setting(hp, "normalize_advantage"):
        return
    batch, n_steps = _ppo_setting(hp, "batch_size"), _ppo_setting(hp, "n_steps")
    if batch < 2:
        raise ConfigError(f"{where}: batch_size must be 2 or more, got {batch} (PPO normalises each minibatch's "
                          "advantages), or set normalize_advantage: false")  # fmt: skip
    if n_steps * n_envs < 2:
        raise ConfigError(f"{where}: n_steps {n_steps} × n_envs {n_envs} makes a rollout of one sample, whose "
                          "advantage PPO cannot normalise; give n_steps or --n-envs 2 or more")  # fmt: skip


def run_copies(config: TrainConfig, hp: dict[str, Any]) -> int:
    """How many env copies a run trains on: ``--n-envs``, else the recipe's ``n_envs``, else 1."""
    return int(config.n_envs if config.n_envs is not None else hp.get("n_envs", 1))


def rollout_note(config: TrainConfig) -> str | None:
    """A line where a new PPO run's rollout (``n_steps`` × ``n_envs``) is not a whole number of minibatches,
    which is what each epoch then does; None otherwise (a resumed run keeps its model's own settings)."""
    if config.algo != "ppo" or config.resume:
        return None
    hp = run_hyperparams(config)
    n_envs = run_copies(config, hp)
    batch, n_steps = _ppo_setting(hp, "batch_size"), _ppo_setting(hp, "n_steps")
    rollout = n_steps * n_envs
    if rollout % batch == 0:
        return None
    full = rollout // batch
    recipe = f"; the recipe has n_envs {hp.get('n_envs', 1)}" if config.n_envs and hp.get("n_envs", 1) != n_envs else ""
    minibatches = f"{full:,} minibatch{'es' if full > 1 else ''} of {batch:,} and one of " if full else "one minibatch of "
    return (f"n_steps {n_steps} × n_envs {n_envs} = a rollout of {rollout:,} samples, which batch_size {batch:,} "
            f"does not divide: each epoch trains on {minibatches}{rollout % batch:,} (for whole minibatches, make "
            f"n_steps × n_envs a multiple of batch_size{recipe})")


def whole_rollouts_note(config: TrainConfig) -> str | None:
    """A line where the timesteps given on the command line (``n_timesteps`` of the options: ``--timesteps``) of a
    new PPO run are not a whole number of rollouts (``n_steps`` × ``n_envs``): PPO collects whole rollouts, so it
    trains up to one rollout more; None otherwise. A recipe's own ``n_timesteps`` trains whole rollouts the same
    way, without a word (as in RL Zoo): a recipe is written for its rollouts, a number typed is not."""
    if config.algo != "ppo" or config.resume or config.n_timesteps is None:
        return None
    hp = run_hyperparams(config)
    rollout = _ppo_setting(hp, "n_steps") * run_copies(config, hp)
    planned = planned_timesteps(config)
    trained = -(-planned // rollout) * rollout
    if trained == planned:
        return None
    return (f"PPO collects whole rollouts of n_steps × n_envs = {rollout:,} steps: {planned:,} timesteps train "
            f"{trained:,}")


def action_noise(hp: dict[str, Any], n_actions: int) -> ActionNoise | None:
    """The exploration noise that ``noise_type``/``noise_std`` describe (checked by :func:`check_action_noise`)."""
    if "noise_type" not in hp:
        return None
    mean, sigma = np.zeros(n_actions), float(hp["noise_std"]) * np.ones(n_actions)
    if hp["noise_type"] == "normal":
        return NormalActionNoise(mean, sigma)
    return OrnsteinUhlenbeckActionNoise(mean, sigma)


def check_recipe(config: TrainConfig) -> dict[str, Any]:
    """A run's algorithm, hyperparameter file and section, and options, checked as far as can be without
    building anything (raises :class:`ConfigError`); returns its hyperparameters."""
    if config.algo not in ALGOS:
        raise ConfigError(f"algo must be one of {sorted(ALGOS)}, got {config.algo!r}")
    for key in ("n_timesteps", "n_envs", "eval_freq", "eval_episodes"):
        value = getattr(config, key)
        if value is not None and not VALUE_RULES[key][0](value):
            raise ConfigError(f"{key} must be {VALUE_RULES[key][1]}, got {value!r}")
    check_vec_env(config.vec_env)
    hp = run_hyperparams(config)
    recipe = recipe_name(config)
    check_algo_keywords(config.algo, hp, recipe)
    check_hyperparameter_values(hp, recipe)
    check_action_noise(config.algo, hp)
    backend = config.backend or (hp.get("env_kwargs") or {}).get("backend")
    check_copies(run_copies(config, hp), backend, config.vec_env)
    check_algo_values(config.algo, hp, run_copies(config, hp), recipe)
    geometry = config.geometry or (hp.get("env_kwargs") or {}).get("geometry")
    if geometry is not None:
        from stewart_gym.envs.ball_env import check_ball_geometry

        check_ball_geometry(geometry)
    if config.twin is not None:
        from stewart_gym.sim.twin import load_twin

        load_twin(config.twin)
    if hp.get("residual"):  # the base as it will run on this build (a dither it cannot give is refused)
        spec = check_residual(hp["residual"])
        residual_base(spec, geometry) if geometry is not None else residual_base(spec)
    return hp


def check_run_env(config: TrainConfig) -> None:
    """A run's env as its options and recipe give it: one copy is built and closed (raises
    :class:`ConfigError` naming where the settings came from, :func:`env_settings_source`)."""
    hp = run_hyperparams(config)
    residual = check_residual(hp["residual"]) if hp.get("residual") else None
    try:
        evaluation_env(config.env_id, 1, config.seed, training_env_kwargs(config, hp), residual).close()
    except ConfigError as exc:
        raise ConfigError(f"the env of {env_settings_source(config)}: {exc}") from None


#: The files a run writes into its folder (besides the folders ``best/``, ``eval/`` and ``tb/``).
RUN_FILES = ("model.zip", "vecnormalize.pkl", "metrics.json", "eval.csv", "config.yaml", "git.txt", RUN_GEOMETRY_FILE)


def check_run_dir(config: TrainConfig, overwrite: bool = False) -> None:
    """Everything about a training run that can be checked before it starts (raises :class:`ConfigError`):
    its recipe and options (:func:`check_recipe`), the run folder (writable; not holding another run's model
    unless ``overwrite`` or resuming) and the run to resume from."""
    from stewart_gym.outputs import no_folders_named, output_dir

    hp = check_recipe(config)
    run = output_dir(config.run_dir)
    no_folders_named(run, RUN_FILES, "the run", "--run-dir")
    if config.resume:
        resume = Path(config.resume)
        model = resume / "model.zip" if resume.is_dir() else resume
        if not model.is_file():
            if resume.is_dir() and (resume / ENSEMBLE_FILE).is_file():  # e.g. shipped-residual: several runs' mean
                raise ConfigError(f"--resume {config.resume}: an ensemble of runs, which train one by one; resume one "
                                  f"of its members, e.g. --resume {resume / 'members' / '0'}")  # fmt: skip
            raise ConfigError(f"--resume {config.resume}: no model at {model}")
        if not zipfile.is_zipfile(model):
            raise ConfigError(f"--resume {config.resume}: {model} is not a Stable-Baselines3 model (not a zip "
                              "archive); give a run folder or a model .zip")  # fmt: skip
        stats = resume_statistics(resume)
        if hp.get("normalize", False) and stats is None:
            raise ConfigError(f"--resume {config.resume}: no normalisation statistics beside the model "
                              "(vecnormalize.pkl); resume from a run folder, its best/best_model.zip or a "
                              "checkpoint")  # fmt: skip
        if stats is not None:
            try:
                with stats.open("rb") as fh:
                    pickle.load(fh)
            except Exception as exc:  # noqa: BLE001 (a damaged pickle raises nearly anything)
                raise ConfigError(f"--resume {config.resume}: {stats}: unreadable normalisation statistics "
                                  f"({type(exc).__name__})") from None  # fmt: skip
        was = saved_algo(model)
        if was is not None and was != config.algo:
            raise ConfigError(f"--resume {config.resume} is a {was.upper()} model and continues as one: give --algo "
                              f"{was} (or train a {config.algo.upper()} policy from scratch)")  # fmt: skip
        check_resumed_observer(config, hp, model)
    in_place = config.resume is not None and _run_folder(Path(config.resume)).resolve() == run.resolve()
    if not overwrite and not in_place and ((run / "model.zip").exists() or (run / "metrics.json").exists()):
        raise ConfigError(f"{run} already holds a trained run; give another --run-dir, --resume it in place, or "
                          "--overwrite")  # fmt: skip


def _run_folder(resume: Path) -> Path:
    """The run folder a model to resume belongs to: a run folder itself, or the folder of its ``model.zip``,
    ``best/best_model.zip`` or ``checkpoints/…zip``."""
    if resume.is_dir():
        return resume
    return resume.parent.parent if resume.parent.name in ("best", "checkpoints") else resume.parent


def check_resumed_observer(config: TrainConfig, hp: dict[str, Any], model: Path) -> None:
    """A resumed policy keeps the observer it was trained behind: if its run's ``config.yaml`` names another
    ``estimator`` than this run's YAML (or the default), that is a :class:`ConfigError` unless ``--estimator``
    was given (an explicit choice). The network reads the observer's estimate, so another observer under it
    is another input, not a fine-tuning."""
    if config.estimator is not None:
        return
    try:
        resumed_cfg = run_config(model)
    except (ValueError, ImportError) as exc:
        raise ConfigError(f"--resume {config.resume}: {exc}") from None
    resumed_hp = resumed_cfg.get("hyperparams") if isinstance(resumed_cfg, dict) else None
    resumed_kwargs = resumed_hp.get("env_kwargs") if isinstance(resumed_hp, dict) else None
    if not isinstance(resumed_kwargs, dict):  # no run configuration to compare with (a bare model, an old run)
        return
    was = str(resumed_kwargs.get("estimator", "lowpass"))
    now = str((hp.get("env_kwargs") or {}).get("estimator", "lowpass"))
    if was != now:
        raise ConfigError(f"--resume {config.resume} was trained behind the {was} observer, but this run's "
                          f"hyperparameters put it behind the {now} one; give --estimator {was} to keep its "
                          f"observer (or --estimator {now} to change it on purpose)")  # fmt: skip


class InProcessVecEnv(DummyVecEnv):
    """SB3's :class:`DummyVecEnv` (the copies step one after another in this process) with the rewards kept as
    float64, as :class:`SubprocVecEnv` returns them: DummyVecEnv's float32 buffer would round them, so the same
    run would learn differently in and out of process. With it a run is the same to the last bit either way."""

    def __init__(self, env_fns: list[Callable[[], Any]]) -> None:
        super().__init__(env_fns)
        self.buf_rews = np.zeros((self.num_envs,), dtype=np.float64)


#: ``--vec-env`` (RL-Zoo's names): where a run's ``n_envs`` env copies step. In this process is the default: an
#: env step (about 0.5 ms) is cheap next to a round trip to a worker process, and on a 2-core virtual machine
#: (bench/bench_train.py) PPO trains about 1.3 times faster in process than with 2 worker processes.
VEC_ENVS: dict[str, type[VecEnv]] = {"dummy": InProcessVecEnv, "subproc": SubprocVecEnv}


#: The most training env copies on PyBullet or MuJoCo (each its own engine); the batched backend takes up to
#: :data:`~stewart_gym.envs.vector.MAX_NUM_ENVS` on one simulator.
MAX_ENGINE_ENVS = 256


def check_copies(n_envs: int, backend: str | None, vec_env: str) -> None:
    """A run's ``n_envs`` and ``vec_env`` for its backend (:class:`ConfigError` otherwise): up to
    :data:`MAX_ENGINE_ENVS` engines, or up to ``MAX_NUM_ENVS`` batched copies, which step together in this process
    (no ``subproc``)."""
    from stewart_gym.envs.vector import MAX_NUM_ENVS

    if backend == "batched":
        if n_envs > MAX_NUM_ENVS:
            raise ConfigError(f"n_envs: the batched backend steps at most {MAX_NUM_ENVS:,} copies, got {n_envs:,}")
        if vec_env != "dummy":
            raise ConfigError(f"vec_env {vec_env}: the batched backend steps its copies together in this process; "
                              "leave --vec-env out")  # fmt: skip
    elif n_envs > MAX_ENGINE_ENVS:
        raise ConfigError(f"n_envs: at most {MAX_ENGINE_ENVS} copies on the {backend or 'default'} backend (each is "
                          f"an engine of its own), got {n_envs:,}; the batched backend takes thousands")  # fmt: skip


def check_vec_env(vec_env: str) -> None:
    """A :data:`VEC_ENVS` name, else :class:`ConfigError`."""
    if vec_env not in VEC_ENVS:
        raise ConfigError(f"vec_env must be one of {', '.join(VEC_ENVS)}, got {vec_env!r}")


def make_env(env_id: str, n_envs: int, seed: int, env_kwargs: dict | None = None,
             residual: dict | None = None, vec_env: str = "dummy") -> VecEnv:  # fmt: skip
    """``n_envs`` monitored copies, stepped as ``vec_env`` says (:data:`VEC_ENVS`; in this process whatever it
    says when ``n_envs`` is 1); with ``residual`` (``{base, scale}``) the agent's action corrects a classical
    controller's (:class:`ResidualAction`).

    The id is passed as ``stewart_gym:<id>`` so that a worker process, which has
    not imported the package, imports it (and so registers the ids) first.
    """
    check_vec_env(vec_env)
    if (env_kwargs or {}).get("backend") == "batched":  # every copy on one batched simulator
        from stable_baselines3.common.vec_env import VecMonitor

        from stewart_gym.sb3_vec import BatchedVecEnv

        batched = BatchedVecEnv(env_id.split(":")[-1], n_envs, env_kwargs, residual)
        batched.seed(seed)
        return VecMonitor(batched)
    vec_cls = VEC_ENVS[vec_env] if n_envs > 1 else InProcessVecEnv
    full_id = env_id if ":" in env_id else f"stewart_gym:{env_id}"
    wrapper = {"wrapper_class": ResidualAction, "wrapper_kwargs": {"residual": residual}} if residual else {}
    start = {"vec_env_kwargs": {"start_method": worker_start_method()}} if vec_cls is SubprocVecEnv else {}
    return make_vec_env(full_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs or {}, vec_env_cls=vec_cls,
                        **wrapper, **start)  # fmt: skip


#: eval.csv's columns (runs made before ``evaluated_s`` lack it; a run continued in place gains it)
EVAL_COLUMNS = ("timesteps", "wall_s", "mean_reward", "success_rate", "evaluated_s")


class _EvalLog(BaseCallback):
    """Every ``eval_freq`` calls, a snapshot of the policy for ``evaluator``; with each evaluation that comes back,
    a row of the learning curve (``eval.csv``: the training's wall time when the snapshot was taken, ``wall_s``,
    and when its evaluation came back, ``evaluated_s``), SB3's ``eval/evaluations.npz``,
    the logger's ``eval/`` values, and the best model so far, as it was when its snapshot was taken, with its
    statistics (``best/``). :meth:`finish` waits for the evaluations still out."""

    def __init__(self, evaluator: InProcessEvaluator | BackgroundEvaluator, eval_freq: int, run: Path,
                 started: float, on_eval: Callable[[dict[str, float]], None] | None = None,
                 continued_from: int | None = None) -> None:  # fmt: skip
        """``continued_from``: a run resumed in place goes on from a model of that many timesteps; its learning
        curve goes on from there (later evaluations, of the branch the resume leaves, are dropped), and its best
        model stays until an evaluation beats it."""
        super().__init__()
        self.evaluator, self.eval_freq, self.run, self.started, self.on_eval = evaluator, eval_freq, run, started, on_eval
        self.best_mean_reward = -math.inf
        self._snapshots: dict[int, tuple[float, bytes, bytes | None]] = {}  # when, model zip, statistics: until evaluated
        self._history: dict[str, list] = {"timesteps": [], "results": [], "ep_lengths": [], "successes": []}
        (run / "best").mkdir(parents=True, exist_ok=True)
        (run / "eval").mkdir(parents=True, exist_ok=True)
        rows = self._continue(continued_from) if continued_from is not None else []
        with (run / "eval.csv").open("w", newline="") as fh:  # (an older run's rows too: in this layout)
            writer = csv.writer(fh)
            writer.writerow(EVAL_COLUMNS)
            writer.writerows([row.get(column, "") for column in EVAL_COLUMNS] for row in rows)

    def _continue(self, timesteps: int) -> list[dict[str, str]]:
        """The run folder's learning curve up to ``timesteps``: its eval.csv rows (returned), its SB3 history, and
        the best reward to beat, where ``best/`` holds a model of those evaluations."""
        curve, history = self.run / "eval.csv", self.run / "eval" / "evaluations.npz"
        if not curve.is_file():
            return []
        with curve.open() as fh:
            rows = [row for row in csv.DictReader(fh) if row.get("timesteps", "").isdigit()]
        kept = [row for row in rows if int(row["timesteps"]) <= timesteps]
        if history.is_file():
            with np.load(history) as saved:
                if "timesteps" in saved.files:
                    keep = saved["timesteps"] <= timesteps
                    self._history.update({key: list(saved[key][keep]) for key in saved.files
                                          if key in self._history and len(saved[key]) == len(keep)})
        rewards = [_number(row["mean_reward"]) for row in rows]
        kept_rewards = [r for r in rewards[:len(kept)] if r is not None] if kept == rows[:len(kept)] else []
        if kept_rewards and (self.run / "best" / "best_model.zip").is_file() and max(kept_rewards) == max(
                r for r in rewards if r is not None):  # fmt: skip  (best/ holds one of the kept evaluations)
            exact = [float(np.mean(r)) for r in self._history["results"]]
            self.best_mean_reward = max(exact) if len(exact) == len(kept) else max(kept_rewards)
        return kept

    def _on_step(self) -> bool:
        if self.n_calls % self.eval_freq == 0:
            taken = time.time() - self.started
            buffer = io.BytesIO()
            self.model.save(buffer)
            zipped = buffer.getvalue()
            norm = self.model.get_vec_normalize_env()
            self._snapshots[self.num_timesteps] = (taken, zipped, None if norm is None else pickle.dumps(norm))
            self.evaluator.submit(self.num_timesteps, self.model, zipped)
        for evaluation in self.evaluator.results():
            self._record(evaluation)
        return True

    def finish(self) -> None:
        """Record the evaluations still out, once they are done."""
        for evaluation in self.evaluator.results(wait=True):
            self._record(evaluation)

    def _record(self, evaluation: Evaluation) -> None:
        taken, zipped, statistics = self._snapshots.pop(evaluation.timesteps)
        mean_reward = float(np.mean(evaluation.episode_rewards))
        success = float(np.mean(evaluation.successes)) if evaluation.successes else float("nan")
        row = {"timesteps": evaluation.timesteps, "wall_s": round(taken, 1), "mean_reward": round(mean_reward, 3),
               "success_rate": success, "evaluated_s": round(time.time() - self.started, 1)}  # fmt: skip
        with (self.run / "eval.csv").open("a", newline="") as fh:
            csv.writer(fh).writerow(row.values())
        history = self._history
        if history["results"] and len(history["results"][0]) != len(evaluation.episode_rewards):
            # a continued run evaluating another number of episodes: SB3's file holds one count; it starts again
            history.update({key: [] for key in history})
        history["timesteps"].append(evaluation.timesteps)
        history["results"].append(evaluation.episode_rewards)
        history["ep_lengths"].append(evaluation.episode_lengths)
        if evaluation.successes:
            history["successes"].append(evaluation.successes)
        np.savez(self.run / "eval" / "evaluations", **{k: v for k, v in history.items() if v})
        self.logger.record("eval/mean_reward", mean_reward)
        self.logger.record("eval/mean_ep_length", float(np.mean(evaluation.episode_lengths)))
        if evaluation.successes:
            self.logger.record("eval/success_rate", success)
        self.logger.dump(evaluation.timesteps)
        if mean_reward > self.best_mean_reward:
            self.best_mean_reward = mean_reward
            (self.run / "best" / "best_model.zip").write_bytes(zipped)
            if statistics is not None:
                (self.run / "best" / "vecnormalize.pkl").write_bytes(statistics)
        if self.on_eval is not None:
            self.on_eval(row)


class _Deadline(BaseCallback):
    """Stop training after ``seconds`` of wall time (keeps results for the time budget); ``reached`` says so."""

    def __init__(self, seconds: float | None) -> None:
        super().__init__()
        self.seconds, self.started, self.reached = seconds, time.time(), False

    def _on_step(self) -> bool:
        self.reached = self.seconds is not None and time.time() - self.started >= self.seconds
        return not self.reached


class _NetworkGaveNaN(Exception):
    """The policy's weights are no longer finite (raised by :class:`_FiniteNetwork`)."""


class _FiniteNetwork(BaseCallback):
    """Ends a run whose network has come apart: as each rollout starts (after the last update), the policy's weights
    must be finite. torch's distributions refuse a NaN mean too, but only where their argument checks are on, and a
    library imported beside (TorchRL) turns them off for the whole process: the NaN actions then reach the env."""

    def _on_rollout_start(self) -> None:
        if not all(bool(torch.isfinite(p).all()) for p in self.model.policy.parameters()):
            raise _NetworkGaveNaN

    def _on_step(self) -> bool:
        return True


class _Progress(BaseCallback):
    """``report(n_envs)`` after each vectorised step."""

    def __init__(self, report: Callable[[int], None]) -> None:
        super().__init__()
        self.report = report

    def _on_step(self) -> bool:
        self.report(self.training_env.num_envs)
        return True


def training_env_kwargs(config: TrainConfig, hp: dict[str, Any]) -> dict[str, Any]:
    """The env keywords a run trains with: the recipe's (:func:`run_env_kwargs`) with the options' backend,
    sensor, estimator and twin in their place."""
    env_kwargs, _ = run_env_kwargs(config, hp)
    for key in ("backend", "sensor", "estimator"):
        if getattr(config, key) is not None:
            env_kwargs[key] = getattr(config, key)
    if config.twin is not None:
        from stewart_gym.sim.twin import load_twin

        env_kwargs["twin"] = load_twin(config.twin).to_mapping()
    return env_kwargs


def planned_timesteps(config: TrainConfig) -> int:
    """The env steps ``config`` trains for: ``n_timesteps`` of the options, else of the hyperparameters."""
    return int(config.n_timesteps if config.n_timesteps is not None
               else run_hyperparams(config).get("n_timesteps", 100_000))  # fmt: skip


def _git_revision() -> str:
    """The git revision of the stewart_gym source that runs (not of the current directory), or the version."""
    from stewart_gym import __version__

    here = Path(__file__).resolve().parent
    installed = f"stewart_gym {__version__} (not a git checkout)"
    try:
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=here, capture_output=True, text=True,
                             check=True).stdout.strip()  # fmt: skip
        if not top or Path(top).resolve() != here.parent:
            return installed
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True,
                             check=True).stdout.strip()  # fmt: skip
        dirty = subprocess.run(["git", "status", "--porcelain", "--", str(here)], cwd=here, capture_output=True,
                               text=True).stdout.strip()  # fmt: skip
        return f"stewart_gym {__version__} at {rev}" + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return installed


def train(config: TrainConfig, max_wall_s: float | None = None,
          on_eval: Callable[[dict[str, float]], None] | None = None,
          callbacks: Sequence[BaseCallback] = (),
          on_progress: Callable[[int], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Train as configured; return the final metrics (also written to ``run_dir/metrics.json``).

    ``on_eval`` is called after each evaluation with that row of the learning curve (``timesteps``,
    ``wall_s``, ``mean_reward``, ``success_rate``, ``evaluated_s``): a sweep reports it to its scheduler. ``callbacks`` (SB3
    callbacks) run after the run's own, e.g. a curriculum (``train/experiments/curriculum.py``).
    ``on_progress(steps)`` is called with the env steps of each vectorised step (of :func:`planned_timesteps`
    in all). A run that ``max_wall_s`` ends has ``"stopped": "max_wall_s"`` in its metrics.
    """
    check_run_dir(config, overwrite=True)  # the options; the CLI has also refused to overwrite another run
    algo_cls = ALGOS[config.algo]
    torch.set_num_threads(1)  # small MLPs: extra threads only fight the envs (or other runs) for the cores
    hp = run_hyperparams(config)

    def option(value: int | None, key: str, default: int) -> int:  # an explicit option wins, even a small one
        return int(value if value is not None else hp.get(key, default))

    n_envs = run_copies(config, hp)
    n_timesteps = option(config.n_timesteps, "n_timesteps", 100_000)
    normalize = hp.get("normalize", False)
    env_kwargs = training_env_kwargs(config, hp)
    hp["env_kwargs"] = env_kwargs  # config.yaml records what was used: a policy keeps its geometry
    eval_freq = option(config.eval_freq, "eval_freq", 20_000)
    eval_episodes = option(config.eval_episodes, "eval_episodes", 20)
    algo_kwargs = {k: v for k, v in hp.items() if k not in RUN_KEYS}
    if "activation_fn" in (algo_kwargs.get("policy_kwargs") or {}):  # a name in the recipe, a torch module here
        name = algo_kwargs["policy_kwargs"]["activation_fn"]
        algo_kwargs["policy_kwargs"] = {**algo_kwargs["policy_kwargs"],
                                        "activation_fn": getattr(torch.nn, ACTIVATIONS[name])}  # fmt: skip
    policy = hp.get("policy", "MlpPolicy")
    residual = check_residual(hp["residual"]) if hp.get("residual") else None
    if residual is not None:
        hp["residual"] = residual  # with the base's design as it is now: a later retune leaves this run alone
    make_eval_env = partial(evaluation_env, config.env_id, eval_episodes, config.seed + EVAL_SEED_OFFSET, env_kwargs,
                            residual)  # fmt: skip
    try:  # built here first: a bad env keyword or value is one error line, before the run folder
        eval_env = make_eval_env()
    except ConfigError as exc:
        raise ConfigError(f"the env of {env_settings_source(config)}: {exc}") from None
    background = config.background_eval if config.background_eval is not None else _cores() >= 2
    run = Path(config.run_dir)
    run.mkdir(parents=True, exist_ok=True)
    recorded = hp
    geometry = env_kwargs.get("geometry")
    if isinstance(geometry, str) and geometry not in PRESETS:  # a file: the run keeps its own copy of the build
        from stewart_gym.presets import load_geometry

        (run / RUN_GEOMETRY_FILE).write_text(load_geometry(geometry).to_toml(), encoding="utf-8")
        recorded = {**hp, "env_kwargs": {**env_kwargs, "geometry": RUN_GEOMETRY_FILE}}
    (run / "config.yaml").write_text(yaml.safe_dump({"options": vars(config), "hyperparams": recorded},
                                                    sort_keys=False), encoding="utf-8")  # fmt: skip
    (run / "git.txt").write_text(_git_revision() + "\n", encoding="utf-8")

    env = make_env(config.env_id, n_envs, config.seed, env_kwargs, residual, config.vec_env)
    resume = Path(config.resume) if config.resume else None
    stats = None
    if resume is not None:
        stats = resume_statistics(resume)
    norm_kwargs = normalize if isinstance(normalize, dict) else {}
    if normalize:
        if stats is not None:
            env = VecNormalize.load(str(stats), env)
            env.obs_rms = FixedStatistics.of(env.obs_rms)  # the resumed policy's inputs keep their meaning
        else:
            env = VecNormalize(env, **{"norm_obs": True, "norm_reward": True, **norm_kwargs})
    eval_norm = {k: v for k, v in norm_kwargs.items() if k != "norm_reward"} if normalize else None
    if background:
        eval_env.close()
        evaluator: InProcessEvaluator | BackgroundEvaluator = BackgroundEvaluator(make_eval_env, algo_cls,
                                                                                  eval_episodes, eval_norm)  # fmt: skip
    else:
        if eval_norm is not None:
            eval_env = VecNormalize(eval_env, training=False, norm_reward=False, **eval_norm)
        evaluator = InProcessEvaluator(eval_env, eval_episodes)
    tb = str(run / "tb") if config.tensorboard else None
    noise = action_noise(hp, int(env.action_space.shape[0]))
    if resume is not None:
        zip_path = resume / "model.zip" if resume.is_dir() else resume
        # the YAML's learning rate (and PPO's clip range) apply to the continued run, e.g. to fine-tune
        custom = {k: algo_kwargs[k] for k in ("learning_rate", "clip_range") if k in algo_kwargs}
        model = algo_cls.load(zip_path, env=env, device="cpu", tensorboard_log=tb, custom_objects=custom)
        model.seed = config.seed  # else the run goes on with the seed the resumed model was trained with
        model.set_random_seed(config.seed)
        if noise is not None:  # not saved with the model
            model.action_noise = noise
    else:
        model = algo_cls(policy, env, seed=config.seed, device="cpu", tensorboard_log=tb, verbose=config.verbose,
                         **({"action_noise": noise} if noise is not None else {}), **algo_kwargs)  # fmt: skip
    if tb is None:  # else SB3 makes an empty tempdir/SB3-<time> folder for its logger on every run
        model.set_logger(make_sb3_logger(str(run), ["stdout"] if config.verbose else []))
    started = time.time()
    deadline = _Deadline(max_wall_s)
    in_place = resume is not None and _run_folder(resume).resolve() == run.resolve()
    evaluations = _EvalLog(evaluator, max(eval_freq // n_envs, 1), run, started, on_eval,
                           continued_from=int(model.num_timesteps) if in_place else None)  # fmt: skip
    every_callback = CallbackList([
        _FiniteNetwork(),
        evaluations,
        CheckpointCallback(max(config.checkpoint_freq // n_envs, 1), str(run / "checkpoints"),
                           save_vecnormalize=bool(normalize)),
        deadline,
        *([_Progress(on_progress)] if on_progress is not None else []),
        *callbacks,
    ])  # fmt: skip
    try:
        if eval_freq <= n_timesteps:  # a worker starts while the training does: ready for the first evaluation
            evaluator.start()
        model.learn(n_timesteps, callback=every_callback, progress_bar=config.progress_bar,
                    reset_num_timesteps=resume is None, tb_log_name=config.algo)  # fmt: skip
        evaluations.finish()
    except (ValueError, _NetworkGaveNaN) as exc:  # (torch's distributions refuse a NaN mean where they check)
        if isinstance(exc, ValueError) and "found invalid values" not in str(exc):
            raise
        raise TrainingDiverged(f"training diverged after {model.num_timesteps:,} steps: the network gave NaN; lower "
                               f"the learning_rate, vf_coef or ent_coef of {recipe_name(config)} (what was saved "
                               f"before, checkpoints and the best evaluated model, is in {run})") from None
    finally:
        evaluator.close()
    wall = time.time() - started
    model.save(run / "model.zip")
    if isinstance(env, VecNormalize):
        env.save(str(run / "vecnormalize.pkl"))
    metrics = {"env_id": config.env_id, "algo": config.algo, "timesteps": int(model.num_timesteps),
               "wall_time_s": round(wall, 1), "n_envs": n_envs, "seed": config.seed}  # fmt: skip
    if deadline.reached:
        metrics["stopped"] = "max_wall_s"
    with (run / "eval.csv").open() as fh:
        rows = [{k: _number(v) for k, v in r.items()} for r in csv.DictReader(fh)]
    if rows:
        metrics["last_eval"] = rows[-1]
        metrics["best_eval_success_rate"] = max((r["success_rate"] for r in rows if r["success_rate"] is not None),
                                                default=None)  # fmt: skip
    (run / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n", encoding="utf-8")
    env.close()
    return metrics


def _cores() -> int:
    """The CPU cores this process may run on."""
    if hasattr(os, "process_cpu_count"):  # Python 3.13
        return os.process_cpu_count() or 1
    if hasattr(os, "sched_getaffinity"):  # Linux
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _number(text: str) -> int | float | None:
    """A CSV cell as a JSON number (None for NaN, and for an empty cell: strict JSON has no NaN)."""
    if not text:
        return None
    value = float(text)
    if value != value:
        return None
    return int(value) if value.is_integer() and "." not in text else value


def evaluation_env(env_id: str, n_episodes: int, seed: int, env_kwargs: dict, residual: dict | None = None) -> VecEnv:
    """A training run's evaluation env, seeded: on the batched backend ``n_episodes`` copies, to play the
    episodes side by side on one batched simulator; on the others one env, to play them in turn."""
    if env_kwargs.get("backend") == "batched":
        env = make_env(env_id, n_episodes, seed, env_kwargs, residual)
    else:
        env = DummyVecEnv([partial(_monitored, env_id, env_kwargs, residual)])
    env.seed(seed)  # the same evaluation episodes, so learning curve and best/, each run
    return env


def _monitored(env_id: str, env_kwargs: dict, residual: dict | None = None) -> Any:
    import gymnasium as gym
    from stable_baselines3.common.monitor import Monitor

    env = gym.make(env_id, **env_kwargs)
    return Monitor(ResidualAction(env, residual) if residual else env)
