"""Sweeps on Ray Tune: many trainings over hyperparameters, env keywords and seeds, on one machine or a cluster.

A sweep file (YAML) names the task and the search space::

    env: StewartBallBalance-v0         # an env id
    algo: ppo                          # ppo, sac, td3 or tqc
    geometry: servo-hexapod            # optional: a preset or TOML file
    n_timesteps: 150000                # per trial
    n_envs: 1                          # env workers per trial = CPUs per trial (batched: copies in one process)
    seeds: [0, 1, 2]                   # every configuration is trained with each seed
    learning_rate: 0.0005              # fixed hyperparameters, named as in stewart_gym/hyperparams/<algo>.yml
    search:
      learning_rate: {loguniform: [1.0e-4, 3.0e-3]}
      n_steps: {grid: [512, 1024]}
      env_kwargs.max_tilt: {uniform: [0.10, 0.20]}
      env_kwargs.randomization.sensor_noise_mm: {choice: [[0.5, 2.0], [0.5, 4.0]]}

Options: ``searcher`` (``random``, the default, which also expands ``grid`` entries, or ``optuna``),
``scheduler`` (``asha``, the default, stops weak trials early on the evaluation's success rate; or ``fifo``),
``metric`` (``success_rate``, default, or ``mean_reward``), ``num_samples``, ``max_concurrent``, ``grace_period``
(timesteps before ASHA may stop a trial), ``eval_freq``, ``eval_episodes``, ``hyperparams`` (the YAML whose
section is the base, default the package's). Everything is checked by :func:`load_sweep` before a trial starts.

Each trial is one call of :func:`stewart_gym.training.train`; its run folder (model, normalisation, learning
curve, metrics and an exported ``bundle/``) is ``OUT/trials/<trial id>``. :func:`run_sweep` writes
``OUT/results.csv`` (every trial, ranked), ``OUT/configs.csv`` (configurations over seeds: mean, min and max),
``OUT/sweep.png`` and ``OUT/best_bundle`` (the best trial's bundle). Ray's own state is ``OUT/ray``: a sweep
resumes from it.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import os
import platform
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stewart_gym.errors import ConfigError
from stewart_gym.inputs import read_yaml
from stewart_gym.outputs import make_parent

if TYPE_CHECKING:
    from stewart_gym.training import TrainConfig

__all__ = ["DOMAINS", "SPEC_KEYS", "SweepSpec", "load_sweep", "rank_trials", "run_sweep", "summarise_configs"]

#: The range kinds of a ``search:`` entry.
DOMAINS = ("choice", "grid", "uniform", "loguniform")
SEARCHERS = ("random", "optuna")
SCHEDULERS = ("asha", "fifo")
METRICS = ("success_rate", "mean_reward")
#: The largest seed a trial takes (as ``train --seed``).
MAX_SEED = 2**31 - 1


@dataclass
class SweepSpec:
    """A checked sweep file (see the module docstring)."""

    env: str
    algo: str
    n_timesteps: int
    n_envs: int = 1
    seeds: list[int] = field(default_factory=lambda: [0])
    geometry: str | None = None
    hyperparams_file: str | None = None
    fixed: dict[str, Any] = field(default_factory=dict)  # hyperparameters; env_kwargs as one dict
    search: dict[str, tuple[str, list]] = field(default_factory=dict)  # name → (domain kind, values)
    searcher: str = "random"
    scheduler: str = "asha"
    metric: str = "success_rate"
    num_samples: int = 1
    max_concurrent: int | None = None
    grace_period: int | None = None
    eval_freq: int | None = None
    eval_episodes: int = 10
    name: str = "sweep"
    batched: bool = False  # the trials train on the batched backend (env_kwargs backend: batched)

    @property
    def cpus_per_trial(self) -> int:
        """The CPUs Ray reserves for a trial: one per env worker, or one for all the copies of a batched trial
        (they step together in the trial's own process)."""
        return 1 if self.batched else self.n_envs

    def trial_count(self) -> int:
        """How many trials the sweep runs: grid points × samples × seeds."""
        grid = math.prod(len(v) for kind, v in self.search.values() if kind == "grid")
        return grid * self.num_samples * len(self.seeds)

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: The keys of a sweep file (YAML) besides the algorithm's hyperparameters.
SPEC_KEYS = {"env", "algo", "n_timesteps", "n_envs", "seeds", "geometry", "hyperparams", "search", "searcher",
              "scheduler", "metric", "num_samples", "max_concurrent", "grace_period", "eval_freq", "eval_episodes",
              "name"}  # fmt: skip


def _whole(value: Any, key: str, least: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value) or value < least:
        raise ConfigError(f"{key} must be a whole number ≥ {least}, got {value!r}")
    return int(value)


def hyperparam_names(algo: str) -> set[str]:
    """What a sweep may set for ``algo``: the algorithm's keywords and the RL-Zoo keys of the YAML files."""
    from stewart_gym.training import RUN_KEYS, algo_keywords

    return (algo_keywords(algo) | set(RUN_KEYS)) - {"n_envs", "n_timesteps", "eval_freq", "eval_episodes"}


def _check_name(name: str, spec: SweepSpec, where: str) -> None:
    """``name`` is a hyperparameter of the algorithm or ``env_kwargs.NAME`` (``env_kwargs.randomization.FIELD``)."""
    from stewart_gym.envs.randomization import RandomizationRanges

    parts = name.split(".")
    if parts[0] == "env_kwargs" and len(parts) >= 2:
        from stewart_gym.envs import make_keywords

        known = make_keywords(spec.env)
        if parts[1] not in known:
            raise ConfigError(f"{where}: {name!r}: {spec.env} takes no keyword {parts[1]!r}; it takes {sorted(known)}")
        if len(parts) == 3 and parts[1] == "randomization":
            ranges = {f.name for f in fields(RandomizationRanges)}
            if parts[2] not in ranges:
                raise ConfigError(f"{where}: {name!r}: no randomisation range {parts[2]!r}; ranges: {sorted(ranges)}")
        elif len(parts) > 2:
            raise ConfigError(f"{where}: {name!r}: give env_kwargs.NAME or env_kwargs.randomization.FIELD")
        return
    known = hyperparam_names(spec.algo)
    if name not in known:
        raise ConfigError(f"{where}: unknown hyperparameter {name!r} for {spec.algo}; give one of {sorted(known)} "
                          "or env_kwargs.NAME")  # fmt: skip


def _check_domain(name: str, entry: Any) -> tuple[str, list]:
    where = f"search.{name}"
    if not isinstance(entry, dict) or len(entry) != 1 or next(iter(entry)) not in DOMAINS:
        raise ConfigError(f"{where}: give one of {{choice: [...]}}, {{grid: [...]}}, {{uniform: [lo, hi]}} or "
                          f"{{loguniform: [lo, hi]}}, got {entry!r}")  # fmt: skip
    kind, values = next(iter(entry.items()))
    if not isinstance(values, list) or not values:
        raise ConfigError(f"{where}: {kind} needs a non-empty list, got {values!r}")
    if kind in ("uniform", "loguniform"):
        numbers = len(values) == 2 and all(not isinstance(v, bool) and isinstance(v, (int, float))
                                           and math.isfinite(v) for v in values)  # fmt: skip
        if not numbers or not values[0] < values[1]:
            raise ConfigError(f"{where}: {kind} needs [lo, hi] with finite lo < hi, got {values!r}")
        if kind == "loguniform" and values[0] <= 0:
            raise ConfigError(f"{where}: loguniform needs 0 < lo < hi, got {values!r}")
        values = [float(v) for v in values]
    for v in values:
        if isinstance(v, float) and not math.isfinite(v):
            raise ConfigError(f"{where}: {v!r} is not a finite number")
    return kind, values


def load_sweep(path: str | Path, *, num_samples: int | None = None, max_concurrent: int | None = None) -> SweepSpec:
    """Read and check a sweep file; raises :class:`ConfigError` naming the key or range that is wrong."""

    from stewart_gym.envs import ENV_IDS
    from stewart_gym.training import ALGOS, check_copies, check_hyperparameter_values, load_hyperparams

    path = Path(path)
    data = read_yaml(path, "sweep file")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of keys (env, algo, n_timesteps, search, ...)")
    for key in ("env", "algo", "n_timesteps"):
        if key not in data:
            raise ConfigError(f"{path}: missing {key!r}")
    if data["env"] not in ENV_IDS:
        raise ConfigError(f"{path}: env must be one of {sorted(ENV_IDS)}, got {data['env']!r}")
    if data["algo"] not in ALGOS:
        raise ConfigError(f"{path}: algo must be one of {sorted(ALGOS)}, got {data['algo']!r}")
    spec = SweepSpec(env=data["env"], algo=data["algo"], n_timesteps=_whole(data["n_timesteps"], "n_timesteps"),
                     name=str(data.get("name", path.stem)))  # fmt: skip
    known_hp = hyperparam_names(spec.algo)
    unknown = sorted(k for k in data if k not in SPEC_KEYS and k not in known_hp)
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {unknown}; sweep keys: {sorted(SPEC_KEYS)}; hyperparameters of "
                          f"{spec.algo}: {sorted(known_hp)}")  # fmt: skip
    spec.n_envs = _whole(data.get("n_envs", 1), "n_envs")
    seeds = data.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds:
        raise ConfigError(f"{path}: seeds must be a non-empty list of whole numbers, got {seeds!r}")
    spec.seeds = [_whole(s, "each seed", 0) for s in seeds]
    if max(spec.seeds) > MAX_SEED:
        raise ConfigError(f"{path}: each seed must be at most {MAX_SEED:,}, got {max(spec.seeds)!r}")
    if len(set(spec.seeds)) != len(spec.seeds):
        raise ConfigError(f"{path}: seeds repeat: {spec.seeds}")
    for key, allowed in (("searcher", SEARCHERS), ("scheduler", SCHEDULERS), ("metric", METRICS)):
        value = data.get(key, getattr(spec, key))
        if value not in allowed:
            raise ConfigError(f"{path}: {key} must be one of {list(allowed)}, got {value!r}")
        setattr(spec, key, value)
    spec.num_samples = _whole(num_samples if num_samples is not None else data.get("num_samples", 1), "num_samples")
    concurrent = max_concurrent if max_concurrent is not None else data.get("max_concurrent")
    spec.max_concurrent = None if concurrent is None else _whole(concurrent, "max_concurrent")
    for key in ("grace_period", "eval_freq"):
        if data.get(key) is not None:
            setattr(spec, key, _whole(data[key], key))
    spec.eval_episodes = _whole(data.get("eval_episodes", 10), "eval_episodes")
    if data.get("geometry") is not None:
        from stewart_gym.envs.ball_env import check_ball_geometry

        check_ball_geometry(data["geometry"])
        spec.geometry = str(data["geometry"])
    if data.get("hyperparams") is not None:
        spec.hyperparams_file = str(data["hyperparams"])
    spec.fixed = {k: v for k, v in data.items() if k in known_hp}
    if "env_kwargs" in spec.fixed:
        if not isinstance(spec.fixed["env_kwargs"], dict):
            raise ConfigError(f"{path}: env_kwargs must be a mapping, got {spec.fixed['env_kwargs']!r}")
        for k in spec.fixed["env_kwargs"]:
            _check_name(f"env_kwargs.{k}", spec, str(path))
    search = data.get("search") or {}
    if not isinstance(search, dict):
        raise ConfigError(f"{path}: search must map names to ranges, got {search!r}")
    for name, entry in search.items():
        _check_name(str(name), spec, f"{path}: search")
        if name == "env_kwargs":
            raise ConfigError(f"{path}: search: sweep env keywords one by one, as env_kwargs.NAME")
        spec.search[str(name)] = _check_domain(str(name), entry)
    base = load_hyperparams(spec.algo, spec.env, spec.hyperparams_file)
    if "env_kwargs.backend" in spec.search:
        raise ConfigError(f"{path}: search: env_kwargs.backend: sweep one backend at a time (a batched trial and an "
                          "engine's need different CPUs)")  # fmt: skip
    env_kwargs = {**(base.get("env_kwargs") or {}), **(spec.fixed.get("env_kwargs") or {})}
    spec.batched = env_kwargs.get("backend") == "batched"
    if spec.batched and "n_envs" not in data:  # the recipe's copies (a batched trial with one copy wastes it)
        spec.n_envs = _whole(base.get("n_envs", 1), "n_envs")
    try:
        check_copies(spec.n_envs, env_kwargs.get("backend"), "dummy")
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    check_hyperparameter_values({**base, **{k: v for k, v in spec.fixed.items() if k != "env_kwargs"}}, str(path))
    for name, (kind, values) in spec.search.items():  # every value a trial may be given (a range: its ends)
        if "." not in name:
            for value in values:
                check_hyperparameter_values({name: value}, f"{path}: search.{name} ({kind})")
    if spec.searcher == "optuna" and any(kind == "grid" for kind, _ in spec.search.values()):
        grids = [n for n, (kind, _) in spec.search.items() if kind == "grid"]
        raise ConfigError(f"{path}: searcher optuna samples; it cannot expand grid entries {grids}: use choice, "
                          "or searcher: random")  # fmt: skip
    if spec.eval_freq is not None and spec.eval_freq > spec.n_timesteps:
        raise ConfigError(f"{path}: eval_freq ({spec.eval_freq}) > n_timesteps ({spec.n_timesteps}): no evaluation "
                          "would be reported")  # fmt: skip
    _check_trials(spec, path)
    return spec


def _check_trials(spec: SweepSpec, path: Path) -> None:
    """Each value a trial may be given, in a trial beside the other entries' first values: the checks that
    ``train`` makes of its recipe and options, and one env built as the trial builds it, so that a value the
    algorithm or the env refuses is one line before Ray starts (a range is checked at its ends)."""
    from stewart_gym.training import check_recipe, check_run_env

    first = {name: values[0] for name, (_, values) in spec.search.items()}
    trials = [("", first)] + [(f" search.{name} = {value!r}:", {**first, name: value})
                              for name, (_, values) in spec.search.items() for value in values[1:]]  # fmt: skip
    for which, config in trials:
        cfg = trial_config(spec, {**config, "seed": max(spec.seeds)}, ".")
        try:
            check_recipe(cfg)
            check_run_env(cfg)
        except ConfigError as exc:
            raise ConfigError(f"{path}:{which} {exc}") from None


# --------------------------------------------------------------------------------------------- the trials
def trial_overrides(spec: SweepSpec, config: dict[str, Any]) -> dict[str, Any]:
    """The hyperparameters of one trial: the fixed ones, then its sampled values (``env_kwargs`` nested)."""
    out: dict[str, Any] = {k: v for k, v in spec.fixed.items() if k != "env_kwargs"}
    env_kwargs: dict[str, Any] = dict(spec.fixed.get("env_kwargs") or {})
    for name in spec.search:
        value = config[name]
        parts = name.split(".")
        if parts[0] != "env_kwargs":
            out[name] = value
        elif len(parts) == 2:
            env_kwargs[parts[1]] = value
        else:
            env_kwargs["randomization"] = {**dict(env_kwargs.get("randomization") or {}), parts[2]: value}
    if env_kwargs:
        out["env_kwargs"] = env_kwargs
    return out


def trial_seed(spec: SweepSpec, config: dict[str, Any]) -> int:
    """A trial's seed: its ``seed`` entry (random search), or the Repeater's index into ``seeds`` (optuna)."""
    if "seed" in config:
        return int(config["seed"])
    return spec.seeds[int(config.get("__trial_index__", 0)) % len(spec.seeds)]


def trial_config(spec: SweepSpec, config: dict[str, Any], run_dir: str) -> TrainConfig:
    """The training run of the trial that Tune gives ``config`` (its sampled values), in ``run_dir``."""
    from stewart_gym.training import TrainConfig

    return TrainConfig(env_id=spec.env, algo=spec.algo, hyperparams=spec.hyperparams_file, run_dir=run_dir,
                       geometry=spec.geometry, seed=trial_seed(spec, config), n_timesteps=spec.n_timesteps,
                       n_envs=spec.n_envs, eval_freq=eval_freq(spec), eval_episodes=spec.eval_episodes,
                       overrides=trial_overrides(spec, config), progress_bar=False, tensorboard=False,
                       # n_envs worker processes, the CPUs Ray reserves; batched copies step together in this one
                       vec_env="dummy" if spec.batched else "subproc",
                       background_eval=False)  # fmt: skip  (the trials fill the cores Ray has: no core to spare)


def eval_freq(spec: SweepSpec) -> int:
    """Env steps between evaluations: ``eval_freq``, else a tenth of the run (a multiple of ``n_envs``)."""
    freq = spec.eval_freq or max(spec.n_timesteps // 10, 1)
    return max(freq // spec.n_envs, 1) * spec.n_envs


def run_trial(config: dict[str, Any], *, spec: dict[str, Any], trials_dir: str) -> None:
    """One trial, in a Ray worker: train with the trial's settings, report each evaluation to Tune, export the
    bundle and report the end. Its run folder is ``trials_dir/<trial id>``."""
    import ray
    from ray import tune

    from stewart_gym.registry import export_policy, resolve_policy
    from stewart_gym.training import train

    sweep = SweepSpec(**spec)
    run_dir = Path(trials_dir) / tune.get_context().get_trial_id()
    node = ray.get_runtime_context().get_node_id()
    host = platform.node()  # (os.uname is not on Windows)
    cfg = trial_config(sweep, config, str(run_dir))
    last: dict[str, Any] = {}

    def report(row: dict[str, float]) -> None:
        last.update(row, env_steps_per_s=round(row["timesteps"] / max(row["wall_s"], 1e-3), 1), node_id=node,
                    host=host, seed=cfg.seed, run_dir=str(run_dir))  # fmt: skip
        if row["timesteps"] < sweep.n_timesteps:  # the last evaluation is reported with the bundle, below: the
            tune.report(dict(last))  # scheduler stops a trial when it reaches n_timesteps

    metrics = train(cfg, on_eval=report)
    bundle = export_policy(resolve_policy(str(run_dir)), run_dir / "bundle", overwrite=True)  # (a trial run again)
    final = {**last, "timesteps": metrics["timesteps"], "wall_s": metrics["wall_time_s"],
             "env_steps_per_s": round(metrics["timesteps"] / max(metrics["wall_time_s"], 1e-3), 1),
             "best_success_rate": metrics.get("best_eval_success_rate"), "bundle": str(bundle), "finished": True}
    tune.report(final)


def _domain(kind: str, values: list) -> Any:
    from ray import tune

    return {"choice": tune.choice, "grid": tune.grid_search, "uniform": lambda v: tune.uniform(*v),
            "loguniform": lambda v: tune.loguniform(*v)}[kind](values)  # fmt: skip


def _tune_config(spec: SweepSpec) -> tuple[dict[str, Any], Any, Any, int]:
    """Ray's param space, search algorithm, scheduler and sample count for ``spec``."""
    from ray.tune.schedulers import ASHAScheduler, FIFOScheduler

    space: dict[str, Any] = {name: _domain(kind, values) for name, (kind, values) in spec.search.items()}
    scheduler = FIFOScheduler()
    if spec.scheduler == "asha":
        grace = spec.grace_period or max(spec.n_timesteps // 4, eval_freq(spec))
        scheduler = ASHAScheduler(time_attr="timesteps", metric=spec.metric, mode="max", max_t=spec.n_timesteps,
                                  grace_period=min(grace, spec.n_timesteps), reduction_factor=2)  # fmt: skip
    if spec.searcher == "optuna":
        from ray.tune.search import Repeater
        from ray.tune.search.optuna import OptunaSearch

        searcher = Repeater(OptunaSearch(metric=spec.metric, mode="max", seed=spec.seeds[0]), repeat=len(spec.seeds))
        return space, searcher, scheduler, spec.num_samples * len(spec.seeds)
    space["seed"] = _domain("grid", spec.seeds) if len(spec.seeds) > 1 else spec.seeds[0]
    return space, None, scheduler, spec.num_samples


# --------------------------------------------------------------------------------------------- the sweep
def check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """``HOST:PORT`` (or ``ray://HOST:PORT``) answers on TCP; else :class:`ConfigError` (Ray itself would retry
    for minutes). ``auto`` is left to Ray, which finds a cluster started on this machine or says there is none."""
    import socket

    if address == "auto":
        return
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(f"--address {address!r}: give auto or HOST:PORT (the head's address, port 6379 by default)")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise ConfigError(f"--address {address}: nothing answers there ({exc.strerror or exc}); start the head with "
                          "`ray start --head` or check the address and the firewall") from None  # fmt: skip


def connect(address: str | None) -> dict[str, Any]:
    """Start a local Ray with this machine's cores (``address`` None) or join a running cluster; its resources."""
    import ray

    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if address is None:  # "local": a Ray of its own, even where another runs here (ray start, another sweep)
        # Ray runs its workers at nice 15, where any busy process on the machine starves them; the trials are this
        # command's work (docs: Sweeps)
        os.environ.setdefault("RAY_worker_niceness", "0")
        # a new local Ray turns token authentication on, and logs a warning that it did: not a word for the user
        notice = logging.getLogger("ray._private.authentication.authentication_token_setup")
        level = notice.level
        notice.setLevel(logging.ERROR)
        try:
            ray.init(address="local", num_cpus=os.cpu_count(), include_dashboard=False,
                     object_store_memory=200 * 1024**2, log_to_driver=False, configure_logging=False)  # fmt: skip
        finally:
            notice.setLevel(level)
    else:
        check_reachable(address)
        try:
            ray.init(address=address, log_to_driver=False, configure_logging=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise ConfigError(f"--address {address}: cannot join a Ray cluster there ({' '.join(str(exc).split())[:200]}"
                              "); start one with `ray start --head` or leave out --address") from None
    return ray.cluster_resources()


def run_sweep(spec: SweepSpec, out: str | Path, *, address: str | None = None, resume: bool = False,
              echo: Callable[[str], None] = print) -> list[dict[str, Any]]:  # fmt: skip
    """Run (or resume) the sweep; write the results table, the per-configuration table, the plot and the best
    bundle under ``out``; return the ranked trial rows."""
    import ray
    from ray import tune

    out = Path(out).resolve()
    state = out / "ray"
    if resume and not state.is_dir():
        raise ConfigError(f"--resume: {out} holds no sweep to resume (no {state}); run it without --resume first")
    if not resume and state.exists():
        raise ConfigError(f"{out} already holds a sweep; give another --out, or --resume it")
    if resume and (out / "sweep.json").is_file():
        saved = json.loads((out / "sweep.json").read_text(encoding="utf-8"))
        changed = sorted(k for k, v in spec.to_dict().items() if json.loads(json.dumps(v)) != saved.get(k))
        if changed:  # Ray restores the search space, scheduler and concurrency it started with
            raise ConfigError(f"--resume: the sweep file or options differ from those {out} was started with "
                              f"({changed}); resume with the same, or start a new sweep in another --out")  # fmt: skip
    import logging  # an interrupted sweep's trials that never reported are rows of the table, not warnings

    logging.getLogger("ray.tune.analysis.experiment_analysis").setLevel(logging.ERROR)
    resources = connect(address)
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "sweep.json").write_text(json.dumps(spec.to_dict(), indent=2) + "\n", encoding="utf-8")
        cpus = int(resources.get("CPU", 0))
        if cpus < spec.cpus_per_trial:
            raise ConfigError(f"each trial needs {spec.cpus_per_trial} CPUs (n_envs) but the cluster has {cpus}")
        where = f" ({spec.n_envs} copies on the batched backend)" if spec.batched else ""
        echo(f"Ray: {len(ray.nodes())} node(s), {cpus} CPUs; {spec.trial_count()} trial(s) of {spec.n_timesteps} "
             f"steps, {spec.cpus_per_trial} CPU(s) each{where}; results in {out}")  # fmt: skip
        trainable = tune.with_resources(tune.with_parameters(run_trial, spec=spec.to_dict(),
                                                             trials_dir=str(out / "trials")),
                                        {"cpu": spec.cpus_per_trial})  # fmt: skip
        if resume:
            tuner = tune.Tuner.restore(str(state), trainable, resume_unfinished=True, resume_errored=True)
        else:
            space, searcher, scheduler, samples = _tune_config(spec)
            tuner = tune.Tuner(
                trainable, param_space=space,
                tune_config=tune.TuneConfig(search_alg=searcher, scheduler=scheduler, num_samples=samples,
                                            max_concurrent_trials=spec.max_concurrent,
                                            reuse_actors=True),  # a worker that has imported torch trains the next
                run_config=tune.RunConfig(name="ray", storage_path=str(out), verbose=1,
                                          failure_config=tune.FailureConfig(max_failures=0, fail_fast=False)),
            )  # fmt: skip
        tuner.fit()
        rows = rank_trials(spec, _result_rows(spec, state))
    finally:
        ray.shutdown()
    write_results(spec, rows, out)
    return rows


def _result_rows(spec: SweepSpec, state: Path) -> list[dict[str, Any]]:
    """One row per trial from Ray's experiment state: its status (``finished``; ``stopped early`` by the
    scheduler; ``error``; ``unfinished`` when the sweep was interrupted first), values, seed and last report."""
    from ray.tune import ExperimentAnalysis

    rows = []
    for trial in ExperimentAnalysis(str(state)).trials:
        metrics, config = trial.last_result or {}, trial.config or {}
        if trial.status == "ERROR":
            status = "error"
        elif trial.status == "TERMINATED":
            status = "finished" if metrics.get("finished") else "stopped early"
        else:
            status = "unfinished"
        row: dict[str, Any] = {"trial": trial.trial_id, "status": status}
        row.update({name: config.get(name) for name in spec.search})
        row["seed"] = metrics.get("seed", trial_seed(spec, config))
        for key in ("timesteps", "success_rate", "best_success_rate", "mean_reward", "wall_s", "env_steps_per_s",
                    "host", "node_id", "run_dir", "bundle"):  # fmt: skip
            row[key] = metrics.get(key)
        if status == "error":
            error = trial.get_error()
            row["error"] = " ".join(str(error).split())[-300:] if error else "failed"
        rows.append(row)
    return rows


def rank_trials(spec: SweepSpec, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows best first: finished before stopped before failed, then by the sweep's metric, then the other one."""
    other = "mean_reward" if spec.metric == "success_rate" else "success_rate"
    order = {"finished": 0, "stopped early": 1, "error": 2, "unfinished": 3}

    def key(r: dict[str, Any]) -> tuple:
        def num(v: Any) -> float:
            return -float(v) if isinstance(v, (int, float)) and v == v else math.inf

        return order.get(r["status"], 4), num(r.get(spec.metric)), num(r.get(other))

    return sorted(rows, key=key)


def summarise_configs(spec: SweepSpec, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Finished trials grouped by configuration (the sampled values, seeds pooled): mean, min and max of the
    success rate and mean reward; best mean success first."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        if r["status"] == "finished":
            groups.setdefault(tuple(repr(r[n]) for n in spec.search), []).append(r)
    out = []
    for members in groups.values():
        entry: dict[str, Any] = {n: members[0][n] for n in spec.search}
        entry["seeds"] = len(members)
        for metric in ("success_rate", "mean_reward"):
            values = [float(m[metric]) for m in members if isinstance(m.get(metric), (int, float))]
            if values:
                entry[f"{metric}_mean"] = round(sum(values) / len(values), 4)
                entry[f"{metric}_min"], entry[f"{metric}_max"] = round(min(values), 4), round(max(values), 4)
        out.append(entry)
    return sorted(out, key=lambda e: (-e.get(f"{spec.metric}_mean", -math.inf), -e["seeds"]))


def write_results(spec: SweepSpec, rows: list[dict[str, Any]], out: Path) -> None:
    """``results.csv``/``.json`` (ranked trials), ``configs.csv`` (over seeds), ``sweep.png`` and ``best_bundle``."""
    columns = list(dict.fromkeys(k for r in rows for k in r))
    with (out / "results.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    (out / "results.json").write_text(json.dumps(rows, indent=2, default=str) + "\n", encoding="utf-8")
    configs = summarise_configs(spec, rows)
    if configs:
        with (out / "configs.csv").open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(k for c in configs for k in c)))
            writer.writeheader()
            writer.writerows(configs)
    plot_sweep(spec, rows, out / "sweep.png")
    best = next((r for r in rows if r["status"] == "finished" and r.get("bundle")), None)
    if best is not None and Path(best["bundle"]).is_dir():
        shutil.rmtree(out / "best_bundle", ignore_errors=True)
        shutil.copytree(best["bundle"], out / "best_bundle")


def plot_sweep(spec: SweepSpec, rows: list[dict[str, Any]], path: Path) -> None:
    """Each configuration's metric over its seeds (dots) and their mean (bar), best first."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    configs = summarise_configs(spec, rows)[:30]
    fig, ax = plt.subplots(figsize=(10, 0.35 * max(len(configs), 3) + 1.2))
    labels = []
    for i, c in enumerate(configs):
        label = ", ".join(f"{_ABBREVIATIONS.get(n, n.replace('env_kwargs.', ''))}={_short(c[n])}" for n in spec.search)
        labels.append(f"{label or 'fixed'} ({c['seeds']} seed{'s' * (c['seeds'] > 1)})")
        key = tuple(repr(c[n]) for n in spec.search)
        values = [r[spec.metric] for r in rows if r["status"] == "finished"
                  and tuple(repr(r[n]) for n in spec.search) == key and r.get(spec.metric) is not None]  # fmt: skip
        ax.barh(i, c.get(f"{spec.metric}_mean", 0.0), color="#9ecae1")
        ax.plot(values, [i] * len(values), "o", color="#08519c", ms=4)
    ax.set_yticks(range(len(labels)), labels, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel(f"{spec.metric} at the end of training (bar: mean over seeds; dots: seeds)")
    ax.set_title(f"{spec.name}: {spec.env}, {spec.algo}, {spec.n_timesteps} steps per trial", fontsize=9)
    fig.tight_layout()
    fig.subplots_adjust(left=max(fig.subplotpars.left, 0.3))
    fig.savefig(make_parent(path), dpi=110)
    plt.close(fig)


_ABBREVIATIONS = {"learning_rate": "lr", "ent_coef": "ent", "batch_size": "batch", "gae_lambda": "λ", "gamma": "γ",
                  "clip_range": "clip"}  # fmt: skip


def _short(value: Any) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)
