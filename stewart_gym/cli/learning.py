"""``stewart-gym`` learning commands: train, evaluate, export, demo."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

from stewart_gym import experiments
from stewart_gym.cli.common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    MAX_SEED,
    add_backend,
    add_estimator,
    add_sensor,
    add_twin,
    int_at_least,
    json_safe,
    output_dir,
    output_file,
    positive_float,
    twin_tables,
)
from stewart_gym.envs import ENV_IDS, trajectory_env_ids
from stewart_gym.envs.targets import TRACK_TRAJECTORIES
from stewart_gym.errors import ConfigError
from stewart_gym.outputs import no_folders_named
from stewart_gym.progress import Progress

__all__ = ["ENV_CHOICES", "POLICY_HELP", "register"]

ENV_CHOICES = tuple(ENV_IDS)
#: The most episodes one evaluate, compare or demo runs (a bigger number is a typo, and would run for days).
MAX_EPISODES = 100_000
#: The most env steps one training run is given (about a week on 2 cores; --max-minutes stops earlier).
MAX_TIMESTEPS = 1_000_000_000
#: ``--algo``: the keys of :data:`stewart_gym.training.ALGOS`, named here so that ``--help`` needs no torch (a test
#: keeps them equal)
ALGO_CHOICES = ("ppo", "sac", "td3", "tqc")
#: ``--vec-env``: the keys of :data:`stewart_gym.training.VEC_ENVS`, for the same reason (a test keeps them equal)
VEC_ENV_CHOICES = ("dummy", "subproc")
SEED_HELP = "the first episode's seed: episode k runs on seed + k, so the same seed gives the same episodes"
POLICY_HELP = ("shipped, shipped-camera, shipped-residual, pid, pid-kalman, lqr, lqr-pid, a run folder, a model .zip, "
               "an ensemble folder, a bundle folder or a PID gains .json")
TWIN_HELP = ("a platform's twin (TOML, see stewart-gym sysid): every episode runs on exactly its physics (the ball's "
             "start and the sensor noise still vary by seed)")
ESTIMATOR_HELP = ("the observer: lowpass (last reading, filtered velocity) or kalman (Kalman filter: the state now, "
                  "through the sensing delay); default the policy's own (what it was trained or tuned behind)")


def cmd_train(args: argparse.Namespace) -> int:
    """Train PPO, SAC, TD3 (Stable-Baselines3) or TQC (sb3-contrib); hyperparameters: stewart_gym/hyperparams/<algo>.yml."""
    from stewart_gym.training import (
        TrainConfig,
        check_run_dir,
        planned_timesteps,
        resume_note,
        rollout_note,
        run_env_kwargs,
        run_hyperparams,
        train,
        whole_rollouts_note,
    )

    cfg = TrainConfig(env_id=args.env, algo=args.algo, hyperparams=args.hyperparams, run_dir=args.run_dir,
                      geometry=args.geometry, backend=args.backend, sensor=args.sensor, estimator=args.estimator,
                      seed=args.seed, n_timesteps=args.timesteps, n_envs=args.n_envs, vec_env=args.vec_env,
                      eval_freq=args.eval_freq, eval_episodes=args.eval_episodes,
                      background_eval=args.background_eval, checkpoint_freq=args.checkpoint_freq,
                      resume=resume_source(args.resume, args.env, args.geometry), twin=args.twin,
                      progress_bar=False,  # the line or bar below instead of SB3's
                      tensorboard=not args.no_tensorboard)  # fmt: skip
    check_run_dir(cfg, overwrite=args.overwrite)
    resumed = resume_note(cfg)
    if resumed:
        print(f"note: {resumed}", file=sys.stderr)
    _, note = run_env_kwargs(cfg, run_hyperparams(cfg))
    if note:
        print(f"note: {note}", file=sys.stderr)
    uneven = rollout_note(cfg)
    for line in (uneven, whole_rollouts_note(cfg)):
        if line:
            print(f"note: {line}", file=sys.stderr)
    total = planned_timesteps(cfg)
    progress = None if args.no_progress else Progress(total, "steps", "train")
    with warnings.catch_warnings():
        if uneven:  # said above, in a line; Stable-Baselines3 says it again in four
            warnings.filterwarnings("ignore", message="You have specified a mini-batch size", category=UserWarning)
        metrics = train(cfg, max_wall_s=None if args.max_minutes is None else args.max_minutes * 60,
                        on_progress=None if progress is None else progress.advance)  # fmt: skip
    if progress is not None:
        progress.close()
    if metrics.get("stopped"):
        print(f"note: stopped by --max-minutes {args.max_minutes:g}: {metrics['timesteps']:,} steps trained "
              f"({total:,} planned); the model is saved as it stands", file=sys.stderr)  # fmt: skip
    print(json.dumps(metrics, indent=2))
    return EXIT_OK


def resume_source(resume: str | None, env_id: str, geometry: str | None) -> str | None:
    """``--resume``: a run folder or model as given, or a shipped policy's run folder by its name."""
    from stewart_gym.registry import SHIPPED_TABLES, resolve_policy

    if resume not in SHIPPED_TABLES:
        return resume
    source = resolve_policy(resume, env_id, geometry)
    return str(source.path.parent if source.path.name == "model.zip" else source.path)


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Evaluate a policy (shipped, pid, a run folder, a model .zip, a bundle) on N seeded episodes."""
    from stewart_gym.evaluation import evaluate, format_table
    from stewart_gym.experiments import (
        EvaluationJob,
        check_can_render,
        episode_figures,
        evaluate_all,
        process_plan,
        resolve_world,
        world_line,
    )
    from stewart_gym.registry import load_for_evaluation

    gif = None if args.gif is None else output_file(args.gif, suffixes=(".gif",))
    plot = None if args.plot is None else output_file(args.plot, suffixes=(".png",))
    source, policy, trained = load_for_evaluation(args.policy, args.env, args.geometry, args.estimator)
    where = resolve_world(source, trained, args.env, args.backend, args.sensor, args.trajectory)
    env_id, env_kwargs = where.env_id, where.env_kwargs
    twin = twin_tables(args.twin)
    if twin is not None:  # exactly that platform: the episodes vary the ball's start and the noise, not the physics
        env_kwargs = {**env_kwargs, "twin": twin}
        where = type(where)(env_id, env_kwargs)
    randomize = not args.no_randomize and twin is None
    if gif:
        check_can_render(env_kwargs.get("backend"))
    processes, parts = process_plan(args.workers, 1, args.episodes)
    progress = Progress(args.episodes, "episodes", "evaluate")
    if parts == 1:
        metrics = evaluate(env_id, policy, episodes=args.episodes, seed=args.seed, randomize=randomize,
                           env_kwargs=env_kwargs, on_progress=progress.advance)  # fmt: skip
    else:  # the episodes split over processes: the same figures
        job = EvaluationJob(args.policy, env_id, args.geometry, args.estimator, env_kwargs, args.episodes, args.seed,
                            randomize)  # fmt: skip
        metrics = evaluate_all([job], parts, processes, progress.advance)[0]
    progress.close()
    if args.json:  # the numbers first, then the GIF and plot: one that cannot be written loses no number
        twin_file = {"twin": args.twin} if args.twin else {}
        print(json.dumps(json_safe({"policy": source.label, **where.describe(), **twin_file, **metrics})), flush=True)
    else:
        print(f"{source.label} on {args.episodes} seeded episodes of {world_line(where.describe())}"
              + (f" ({args.twin})" if args.twin else ""))  # fmt: skip
        print(format_table({source.label: metrics}), flush=True)
    if gif or plot:
        episode_figures(env_id, policy, env_kwargs, args.seed, randomize, gif, plot,
                        f"{source.label} on {world_line(where.describe())}")  # fmt: skip
    return EXIT_OK


def cmd_compare(args: argparse.Namespace) -> int:
    """Evaluate several policies on the same seeded episodes and pair the first with each of the others, seed by
    seed: the difference in success, RMS error, final error and settling time, with a 95 % bootstrap interval and
    a verdict (better, worse, or a tie the episodes cannot tell apart)."""
    from stewart_gym.evaluation import format_paired, format_table
    from stewart_gym.experiments import compare, compare_setup, process_plan, world

    policies = args.policies
    if len(policies) < 2:
        raise ConfigError(f"compare needs 2 or more policies, got {len(policies)}: add the one to compare with, "
                          "e.g. stewart-gym compare shipped-residual pid-kalman lqr")  # fmt: skip
    def same(spec: str) -> str:  # a path as the file it names (./b1 is b1), a name as itself
        return str(Path(spec).resolve()) if Path(spec).exists() else spec

    twice = sorted({p for p in policies if [same(q) for q in policies].count(same(p)) > 1})
    if twice:
        raise ConfigError(f"the same policy is given more than once ({', '.join(twice)}); give each policy once")
    twin = twin_tables(args.twin)
    randomize = not args.no_randomize and twin is None  # a twin: exactly that platform
    env_id, geometry, env_kwargs = compare_setup(policies, args.env, args.geometry, args.backend, args.sensor,
                                                 args.trajectory, twin)  # fmt: skip
    processes, _ = process_plan(args.workers, len(policies), args.episodes)
    world_line = world(env_id, next(iter(env_kwargs.values())))
    print(f"{len(policies)} policies on {args.episodes} seeded episodes (seeds {args.seed}…{args.seed + args.episodes - 1}"
          f"{', domain randomisation' if randomize else (f', the twin {args.twin}' if twin else ', nominal physics')}) "
          f"of {env_id} "
          f"on {geometry}, {world_line['backend']}, sensor {world_line['sensor']}; {processes} "
          f"process{'es' if processes > 1 else ''} at a time…", flush=True,
          file=sys.stderr if args.json else sys.stdout)  # fmt: skip
    progress = Progress(args.episodes * len(policies), "episodes", "compare")
    results, rows = compare(policies, env_id, args.episodes, args.seed, randomize, geometry, args.backend,
                            args.sensor, args.trajectory, args.workers, progress.advance, twin)  # fmt: skip
    progress.close()
    if args.json:
        print(json.dumps(json_safe({**world_line, "geometry": geometry, "episodes": args.episodes, "seed": args.seed,
                                    "randomize": randomize, "twin": args.twin, "policies": results,
                                    "paired": rows})))  # fmt: skip
    else:
        labels = column_labels(policies)
        print()
        for spec, label in labels.items():
            if label != spec:
                print(f"{label}: {spec}")
        print(format_table({labels[spec]: result for spec, result in results.items()}))
        print()
        print(format_paired([{**r, "a": labels[r["a"]], "b": labels[r["b"]]} for r in rows]))
    return EXIT_OK


def column_labels(specs: list[str]) -> dict[str, str]:
    """A short column label per policy for ``compare``'s table: a name as given, a path by its last part (more
    of it where two would read alike), so that a long path does not widen every column."""
    parts = {spec: Path(spec).parts or (spec,) for spec in specs}
    for n in range(1, max(len(p) for p in parts.values()) + 1):
        labels = {spec: "/".join(p[-n:]) for spec, p in parts.items()}
        if len(set(labels.values())) == len(labels):
            return labels
    return {spec: spec for spec in specs}


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: evaluate the shipped learned policies next to the PID + Kalman and the LQR on the same seeded
    episodes, pair the best learned one with each, seed by seed; write a GIF and a pulse-width plot of it."""
    from stewart_gym.evaluation import format_paired, format_table, paired_rows
    from stewart_gym.experiments import (
        EvaluationJob,
        check_can_render,
        demo_policies,
        episode_figures,
        evaluate_all,
        process_plan,
        resolve_world,
        world,
        world_line,
    )
    from stewart_gym.registry import load_for_evaluation
    from stewart_gym.sim.engines import default_backend

    out = output_dir(args.out)
    no_folders_named(out, ("demo.gif", "demo_pulses.png", "demo_metrics.json"), "the demo", "--out")
    env_id = "StewartBallBalance-v0"
    names = demo_policies(env_id, args.geometry)
    twin = twin_tables(args.twin)
    randomize = twin is None  # a twin: exactly that platform
    loaded = {}
    for name in names:  # every policy loaded before the output folder and the first evaluation
        source, policy, env_kwargs = load_for_evaluation(name, env_id, args.geometry)
        kwargs = resolve_world(source, env_kwargs, env_id, args.backend).env_kwargs
        loaded[name] = (policy, kwargs if twin is None else {**kwargs, "twin": twin})
    engine = loaded[names[0]][1].get("backend") or default_backend()
    gif: Path | None = out / "demo.gif"
    if engine in ("mujoco", "batched"):  # MuJoCo draws with OpenGL, which a headless machine may lack, the batched
        # backend not at all: then no GIF, said why
        try:
            check_can_render(engine)
        except ConfigError as exc:
            gif = None
            print(f"note: no GIF: {exc}", file=sys.stderr)
    processes, parts = process_plan(args.workers, len(names), args.episodes)
    physics = "with domain randomisation" if twin is None else f"on the twin {args.twin}"
    print(f"evaluating {', '.join(names)} on the same {args.episodes} seeded episodes {physics} "
          f"({engine}), {processes} process{'es' if processes > 1 else ''} at a time…", flush=True)  # fmt: skip
    jobs = [EvaluationJob(name, env_id, args.geometry, None, env_kwargs, args.episodes, args.seed, randomize)
            for name, (_, env_kwargs) in loaded.items()]  # fmt: skip
    progress = Progress(args.episodes * len(jobs), "episodes", "demo")
    results = dict(zip(names, evaluate_all(jobs, parts, processes, progress.advance)))
    progress.close()
    print()
    print(format_table(results))
    print()
    print(format_paired(paired_rows(results, names[0])))
    policy, env_kwargs = loaded[names[0]]
    with tempfile.TemporaryDirectory(prefix="stewart-gym-demo-") as scratch:  # the three files made, then moved in
        # together: a run stopped on the way leaves the folder as it was (or none), not new files beside old ones
        work = Path(scratch)
        (work / "demo_metrics.json").write_text(json.dumps(json_safe(results), indent=2) + "\n", encoding="utf-8")
        episode_figures(env_id, policy, env_kwargs, args.seed, randomize, gif and work / gif.name,
                        work / "demo_pulses.png", f"{names[0]} on {world_line(world(env_id, env_kwargs))}")  # fmt: skip
        out.mkdir(parents=True, exist_ok=True)
        for made in work.iterdir():
            shutil.move(str(made), out / made.name)
    wrote = [str(p) for p in (gif, out / "demo_pulses.png") if p is not None]
    print(f"\nwrote {', '.join(wrote)} (policy {names[0]}) and {out / 'demo_metrics.json'}")
    return EXIT_OK


def cmd_export(args: argparse.Namespace) -> int:
    """Export a policy (shipped, pid, a run folder, a model .zip) to a deployable ONNX/JSON bundle."""
    from stewart_gym.registry import CLASSICAL, SHIPPED_TABLES, export_policy, resolve_policy, same_geometry

    out = output_dir(args.out)
    source = resolve_policy(args.policy, args.env, args.geometry, args.estimator)
    named = args.policy in (*SHIPPED_TABLES, *CLASSICAL)
    if args.geometry and not named and not same_geometry(args.geometry, source.geometry):
        raise ConfigError(f"{args.policy} was trained for geometry {source.geometry_label!r}, not {args.geometry!r}")
    if args.env and not named and source.env_id != args.env:
        raise ConfigError(f"{args.policy} was trained on {source.env_id}, not {args.env}; leave out --env")
    folder = export_policy(source, out, overwrite=args.overwrite)
    print(f"bundle written to {folder} ({source.env_id}, action mode {source.action_mode})")
    return EXIT_OK


def cmd_ensemble(args: argparse.Namespace) -> int:
    """Average several trained networks (one recipe, different seeds) into one policy folder: it acts with the
    mean of their actions, and evaluates, exports and deploys like a run folder."""
    from stewart_gym.registry import resolve_policy, write_ensemble

    out = output_dir(args.out)
    folder = write_ensemble(args.runs, out, note=args.note)
    source = resolve_policy(str(folder))
    print(f"ensemble of {len(args.runs)} networks written to {folder} ({source.env_id}, action mode "
          f"{source.action_mode}); evaluate it with: stewart-gym evaluate --policy {folder}")  # fmt: skip
    return EXIT_OK


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run a sweep of trainings on Ray Tune (this machine, or a cluster with --address); see `stewart_gym.sweep`."""
    from stewart_gym.sweep import load_sweep, run_sweep

    spec = load_sweep(args.config, num_samples=args.num_samples, max_concurrent=args.max_concurrent)
    out = output_dir(args.out or f"sweeps/{spec.name}")
    rows = run_sweep(spec, out, address=args.address, resume=args.resume)
    counts = {s: sum(r["status"] == s for r in rows) for s in ("finished", "stopped early", "error", "unfinished")}
    print(f"{len(rows)} trial(s): {counts['finished']} finished, {counts['stopped early']} stopped early by the "
          f"scheduler, {counts['error']} failed"
          + (f", {counts['unfinished']} unfinished" if counts["unfinished"] else ""))  # fmt: skip
    for r in rows:
        if r["status"] == "error":
            print(f"  trial {r['trial']} failed: {r.get('error')}")
    for r in rows[:5]:
        values = ", ".join(f"{n}={r[n]}" for n in spec.search)
        print(f"  {r['status']:13s} {spec.metric} {r.get(spec.metric)}  seed {r['seed']}  {values}")
    best = out / "best_bundle"
    print(f"results: {out / 'results.csv'}, {out / 'configs.csv'}, {out / 'sweep.png'}"
          + (f"; best bundle: {best}" if best.is_dir() else "; no trial finished, so no bundle"))  # fmt: skip
    if counts["unfinished"]:
        print(f"error: interrupted with {counts['unfinished']} trial(s) unfinished; finish them with: stewart-gym sweep "
              f"{args.config} --out {out} --resume", file=sys.stderr)  # fmt: skip
        return EXIT_INTERRUPTED
    return EXIT_OK if counts["finished"] else EXIT_FAILED


def add_episodes(p: argparse.ArgumentParser, at_least: int) -> None:
    """The episodes ``evaluate`` and ``compare`` run: the track's trajectory, how many, the first seed, and whether
    the physics is randomised."""
    p.add_argument("--trajectory", choices=TRACK_TRAJECTORIES,
                   help=f"the moving target of {' or '.join(trajectory_env_ids())} (default circle, whatever the "
                        "policy was trained on; mixed draws one per episode)")  # fmt: skip
    p.add_argument("--episodes", type=int_at_least(at_least, MAX_EPISODES), default=100,
                   help=f"how many (at most {MAX_EPISODES:,}; default 100)")  # fmt: skip
    p.add_argument("--seed", type=int_at_least(0, MAX_SEED), default=0, help=SEED_HELP)
    p.add_argument("--no-randomize", action="store_true", help="nominal physics instead of domain randomisation")


def add_workers(p: argparse.ArgumentParser) -> None:
    """``--workers`` of ``evaluate``, ``compare`` and ``demo`` (:func:`evaluate_all`)."""
    p.add_argument("--workers", type=int_at_least(1, 256), help="processes at once (default: one per core): one per "
                   "policy, and a policy's episodes split between them where there are more (the same figures; "
                   f"by default only where each gets {experiments.EPISODES_PER_PROCESS} episodes or more)")


def register(sub: Any) -> None:
    """Add the learning subcommands to the ``stewart-gym`` parser."""
    p = sub.add_parser("train", help=cmd_train.__doc__, description=cmd_train.__doc__)
    p.add_argument("--env", choices=ENV_CHOICES, default="StewartBallBalance-v0", help="the task to train for")
    p.add_argument("--algo", choices=ALGO_CHOICES, default="ppo", help="the learning algorithm")
    p.add_argument("--geometry", help="preset or TOML file of the platform to train for (default: the YAML's, else "
                                      "servo-hexapod)")
    add_backend(p, "physics engine to train in (default: the YAML's, else pybullet; batched: many copies at once)")
    add_sensor(p, "ball sensor model to train with (default: the YAML's, else panel)")
    add_estimator(p, "the observer to train behind (default: the YAML's, else lowpass)")
    p.add_argument("--hyperparams", help="YAML file, or the name of a shipped one, such as ppo_residual (default "
                                         "stewart_gym/hyperparams/<algo>.yml)")
    p.add_argument("--run-dir", default="runs/latest", help="folder for the model, statistics, curves and logs")
    p.add_argument("--overwrite", action="store_true", help="train into a run folder that already holds a model")
    p.add_argument("--seed", type=int_at_least(0, MAX_SEED), default=0,
                   help="the run's seed: the network's start, the training envs' (seed … seed + n_envs − 1) and the "
                        "evaluations' episodes (from seed + 10000)")  # fmt: skip
    p.add_argument("--timesteps", type=int_at_least(1, MAX_TIMESTEPS), help="override n_timesteps")
    p.add_argument("--n-envs", type=int_at_least(1, 1_000_000),
                   help="override n_envs: up to 256 on pybullet or mujoco, 1,000,000 on batched")
    p.add_argument("--vec-env", choices=VEC_ENV_CHOICES, default="dummy",
                   help="where the n_envs env copies step: dummy, one after another in this process (default: an "
                        "env step is cheaper than a round trip to another process), or subproc, a worker process "
                        "each (bench/bench_train.py measures both); the same run either way, to the last bit. "
                        "The batched backend's copies step together in this process (dummy)")
    p.add_argument("--eval-freq", type=int_at_least(1, MAX_TIMESTEPS), help="env steps between evaluations")
    p.add_argument("--eval-episodes", type=int_at_least(1, 10_000),
                   help="episodes per evaluation during training (default: the YAML's evaluation section, else 20)")
    p.add_argument("--background-eval", action=argparse.BooleanOptionalAction,
                   help="evaluate in a second process while the training goes on (default: where the machine has 2 "
                        "cores or more); the same evaluations either way")  # fmt: skip
    p.add_argument("--checkpoint-freq", type=int_at_least(1, MAX_TIMESTEPS), default=100_000,
                   help="env steps between checkpoints (checkpoints/rl_model_<n>_steps.zip, with their statistics; "
                        "default 100000)")  # fmt: skip
    p.add_argument("--resume", help="run folder or checkpoint .zip to continue from, or a shipped policy's name "
                                    "(shipped, shipped-camera) to fine-tune it; with the run's own hyperparameters "
                                    "unless --hyperparams is given (its learning curve goes on where --run-dir is "
                                    "that run)")
    add_twin(p, "a platform's twin (TOML, see stewart-gym sysid): train for it, each episode's physics drawn narrowly "
                "around its values")
    p.add_argument("--max-minutes", type=positive_float, help="stop after this much wall time")
    p.add_argument("--no-progress", action="store_true", help="no progress bar or progress lines")
    p.add_argument("--no-tensorboard", action="store_true", help="no TensorBoard log (tb/ in the run folder)")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("evaluate", help=cmd_evaluate.__doc__, description=cmd_evaluate.__doc__)
    p.add_argument("--env", choices=ENV_CHOICES, help="default: the env the policy was trained for (balance for pid)")
    p.add_argument("--policy", default="shipped", help=POLICY_HELP)
    p.add_argument("--geometry", help="the platform: picks the shipped policy or sets the PID's; a trained policy "
                                      "runs on its own (default servo-hexapod)")
    add_backend(p, "physics engine to evaluate in (default: the one the policy was trained in, else pybullet; a "
                   "policy trained in batched: pybullet)")
    add_sensor(p, "ball sensor model (default: the one the policy was trained with, else panel)")
    add_estimator(p, ESTIMATOR_HELP)
    add_episodes(p, at_least=1)
    add_workers(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_twin(p, TWIN_HELP)
    p.add_argument("--gif", help="write a GIF of one episode from the 100 mm offset")
    p.add_argument("--plot", help="write the ball path and pulse widths of that episode (PNG)")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("compare", help=cmd_compare.__doc__.split(":")[0] + ".", description=cmd_compare.__doc__)
    p.add_argument("policies", nargs="+", metavar="POLICY", help=f"2 or more, the first paired with each other: "
                                                                  f"{POLICY_HELP}")  # fmt: skip
    p.add_argument("--env", choices=ENV_CHOICES, help="default: the env the first policy was trained for")
    p.add_argument("--geometry", help="the platform (default: the one a trained policy given by path was trained for, "
                                      "else servo-hexapod); named policies adapt to it")  # fmt: skip
    add_backend(p, "physics engine (default: the one the policies were trained in, else pybullet; batched: "
                   "pybullet)")
    add_sensor(p, "ball sensor model (default: the one the policies were trained with, else panel)")
    add_episodes(p, at_least=2)
    add_workers(p)
    add_twin(p, TWIN_HELP)
    p.add_argument("--json", action="store_true", help="print one JSON object: each policy's metrics and the pairs")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("export", help=cmd_export.__doc__, description=cmd_export.__doc__)
    p.add_argument("--policy", default="shipped", help=POLICY_HELP)
    p.add_argument("--env", choices=ENV_CHOICES, help="which shipped policy (default balance)")
    p.add_argument("--geometry", help="which shipped policy or PID (default servo-hexapod); the bundle records it")
    p.add_argument("--out", required=True, help="bundle folder (new, or empty)")
    p.add_argument("--overwrite", action="store_true", help="replace the bundle --out holds already")
    add_estimator(p, ESTIMATOR_HELP + "; the bundle records it and deploy uses it")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("ensemble", help=cmd_ensemble.__doc__.split(":")[0] + ".", description=cmd_ensemble.__doc__)
    p.add_argument("runs", nargs="+", metavar="RUN", help="run folders or model .zip files, trained alike (2 or more)")
    p.add_argument("--out", required=True, help="the ensemble folder to write (new, or empty)")
    p.add_argument("--note", default="", help="free text stored in ensemble.json (e.g. the recipe)")
    p.set_defaults(func=cmd_ensemble)

    p = sub.add_parser("sweep", help=cmd_sweep.__doc__, description=cmd_sweep.__doc__)
    p.add_argument("config", help="sweep file (YAML): env, algo, n_timesteps, n_envs, seeds, fixed hyperparameters "
                                  "and search")
    p.add_argument("--address", help="join a running Ray cluster: auto or HOST:PORT (default: start Ray on this "
                                     "machine with all its cores)")
    p.add_argument("--num-samples", type=int_at_least(1, 100_000), help="override the file's num_samples")
    p.add_argument("--max-concurrent", type=int_at_least(1, 1024), help="at most this many trials at once")
    p.add_argument("--out", help="folder for the trials, tables, plot and best bundle (default sweeps/<name>); on a "
                                 "cluster, storage every node mounts at the same path")
    p.add_argument("--resume", action="store_true", help="continue an interrupted sweep in --out")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("demo", help=cmd_demo.__doc__, description=cmd_demo.__doc__)
    p.add_argument("--episodes", type=int_at_least(1, MAX_EPISODES), default=20,
                   help="seeded episodes per policy (the same for each)")
    add_backend(p, "physics engine (default: PyBullet if installed, else MuJoCo; the GIF needs OpenGL with mujoco)")
    p.add_argument("--geometry", help="the platform (default servo-hexapod; the shipped policy exists for the presets "
                                      "listed by `stewart-gym evaluate --policy shipped --geometry X`)")
    p.add_argument("--seed", type=int_at_least(0, MAX_SEED), default=0, help=SEED_HELP)
    p.add_argument("--out", default="out", help="folder for the GIF, plot and metrics")
    add_twin(p, TWIN_HELP)
    add_workers(p)
    p.set_defaults(func=cmd_demo)
