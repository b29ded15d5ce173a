"""Evaluations as the commands run them: the world a policy runs in, several policies on the same seeded
episodes split over processes, what ``compare`` and ``demo`` compare, and the figures of one episode.

The command line parses and prints; this module does the work, and is usable from Python::

    from stewart_gym.experiments import compare
    results, rows = compare(["shipped-residual", "pid-kalman"], episodes=20)

:func:`resolve_world` is the one place that decides the world of an evaluation: the env id, the build, the
physics engine and the ball sensor, from the policy and what the user asked for.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from stewart_gym.envs import trajectory_env_ids
from stewart_gym.errors import ConfigError

__all__ = ["DEMO_CLASSICAL", "DEMO_LEARNED", "EPISODES_PER_PROCESS", "WORLD_DEFAULTS", "EvaluationJob", "World",
           "check_can_render", "check_trajectory", "compare", "compare_setup", "demo_policies", "episode_figures",
           "evaluate_all", "evaluate_part", "in_world", "process_plan", "resolve_world", "trained_world", "worker_setup",
           "world", "world_line"]

#: The env's physics engine and ball sensor where none is asked for.
WORLD_DEFAULTS = {"backend": "pybullet", "sensor": "panel"}
#: Engines for training only: a policy trained in one is evaluated, by default, in the default engine (PyBullet),
#: the reference it must hold up in; ``--backend batched`` still evaluates it there.
TRAINING_BACKENDS = ("batched",)


@dataclass(frozen=True)
class World:
    """Where a policy runs: the env id and the env keywords (its build, observation and action as trained, the
    physics engine and the ball sensor, the track's trajectory)."""

    env_id: str
    env_kwargs: dict

    def describe(self) -> dict[str, str]:
        """The env id, physics engine and ball sensor (what ``--json`` reports)."""
        return world(self.env_id, self.env_kwargs)


def resolve_world(source: Any, env_kwargs: dict, env_id: str | None = None, backend: str | None = None,
                  sensor: str | None = None, trajectory: str | None = None) -> World:  # fmt: skip
    """The :class:`World` a resolved policy (``source``, with the env keywords it was trained for) runs in: the
    env id asked for, else its own; the engine and sensor asked for, else the ones it was trained with, else
    :data:`WORLD_DEFAULTS`; the track's ``trajectory`` where the target moves (else a :class:`ConfigError`)."""
    env = env_id or source.env_id
    check_trajectory(env, trajectory)
    kwargs = in_world(env_kwargs, source, backend, sensor)
    if trajectory is not None:
        kwargs["trajectory"] = trajectory
    return World(env, kwargs)


def check_trajectory(env_id: str, trajectory: str | None) -> None:
    """``--trajectory`` only where the target moves: else one ``error:`` line naming the envs that take it."""
    moving = trajectory_env_ids()
    if trajectory is not None and env_id not in moving:
        raise ConfigError(f"--trajectory sets a moving target, and {env_id} has a fixed one: add --env "
                          f"{' or '.join(moving)}, or leave out --trajectory")  # fmt: skip


class EvaluationJob(NamedTuple):
    """One policy's evaluation for :func:`evaluate_all`: what :func:`~stewart_gym.registry.load_for_evaluation`
    loads it from (in a worker process too) and the arguments of :func:`~stewart_gym.evaluation.evaluate`."""

    spec: str
    env_id: str
    geometry: str | None
    estimator: str | None
    env_kwargs: dict
    episodes: int
    seed: int
    randomize: bool


#: The most worker processes a pool waits on under Windows (its limit of handles waited on at once, less 3).
WINDOWS_MAX_WORKERS = 61

#: Episodes a process gets at least when the episodes are split without ``--workers``: starting one (Python,
#: torch, the policy) costs seconds, about what 2–5 episodes take.
EPISODES_PER_PROCESS = 10


def process_plan(requested: int | None, jobs: int, episodes: int) -> tuple[int, int]:
    """(processes, parts) for :func:`evaluate_all`: ``jobs`` evaluations of ``episodes`` episodes each, on
    ``requested`` processes (``--workers``), else one per core. Each job's episodes are split into ``parts``
    contiguous parts where there are more processes than jobs: as many as ``--workers`` asks for, and by
    default only as many as give each part :data:`EPISODES_PER_PROCESS` episodes or more."""
    workers = requested or os.cpu_count() or 1
    least = 1 if requested else EPISODES_PER_PROCESS
    parts = max(1, min(workers // jobs, episodes // least))
    return min(workers, jobs * parts), parts


def evaluate_all(jobs: list[EvaluationJob], parts: int, processes: int,
                 on_progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """Each job's :func:`~stewart_gym.evaluation.evaluate` figures, in order (:func:`process_plan` gives
    ``parts`` and ``processes``): each job's episodes split into ``parts`` contiguous parts, run ``processes``
    at a time, each in a process started afresh that loads its policy, or in this process when there is one
    process or one part in all. An episode depends only on its seed, so the figures are those of one process,
    to the last bit. ``on_progress(amount)`` is told of the episodes as they are run, in whichever process (the
    jobs' episodes in all)."""
    from stewart_gym.evaluation import summarise

    tasks = [(job, [int(k) for k in chunk]) for job in jobs
             for chunk in np.array_split(np.arange(job.episodes), parts)]  # fmt: skip
    if processes == 1 or len(tasks) == 1:
        results = [evaluate_part(task, on_progress) for task in tasks]
    else:
        import multiprocessing
        import queue as queues
        from concurrent.futures import ProcessPoolExecutor

        context = multiprocessing.get_context("spawn")
        reports = context.Queue()  # the workers' progress, read here while they run
        others = set(context.active_children())
        most = WINDOWS_MAX_WORKERS if sys.platform == "win32" else processes  # (Windows waits on 61 at most)
        with ProcessPoolExecutor(min(processes, len(tasks), most), mp_context=context, initializer=worker_setup,
                                 initargs=(reports,)) as pool:  # fmt: skip
            try:
                with ctrl_c_held_while_workers_start():
                    futures = [pool.submit(evaluate_part, task) for task in tasks]
                while not all(f.done() for f in futures):
                    try:
                        amount = reports.get(timeout=0.2)
                    except queues.Empty:
                        continue
                    if on_progress is not None:
                        on_progress(amount)
            except BaseException:  # a stop (Ctrl-C, SIGTERM) or a failure here: the workers stop too, at once
                for worker in set(context.active_children()) - others:
                    worker.terminate()
                raise
            results = [f.result() for f in futures]
    return [summarise(job.env_id, job.episodes, job.seed, job.randomize,
                      [part for (owner, _), part in zip(tasks, results) if owner is job]) for job in jobs]  # fmt: skip


@contextlib.contextmanager
def ctrl_c_held_while_workers_start() -> Iterator[None]:
    """While the worker processes start (the pool starts them as the tasks are submitted): SIGINT blocked in this
    thread, which a process started from it keeps, so that a terminal's Ctrl-C while a worker still loads (seconds:
    Python, torch, the policy) waits in that worker until :func:`worker_setup` ends it without a word (no traceback
    of its import). A Ctrl-C in these moments is held here too (noted where another thread takes it), and raised as
    :class:`KeyboardInterrupt` as soon as the tasks are submitted. Where signals cannot be blocked (Windows), SIGINT
    is ignored in these moments instead."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if not hasattr(signal, "pthread_sigmask"):
        before = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, before)
        return
    held: list[int] = []
    before = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # one that waited here runs the handler above
        signal.signal(signal.SIGINT, before)
    if held:
        raise KeyboardInterrupt


#: In a worker process of :func:`evaluate_all`: where its progress goes (set by :func:`worker_setup`).
_REPORTS: list[Any] = []


def worker_setup(reports: Any) -> None:
    """In a worker process: no ``note:`` lines (the parent has said them when it loaded the policies), the queue
    that carries its progress to the parent, and a Ctrl-C (which a terminal sends to the parent and its workers
    alike) ends it without a word: the parent says the one line."""
    import logging
    import signal

    logging.getLogger("stewart_gym").setLevel(logging.ERROR)
    _REPORTS[:] = [reports]
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # the system's default: the process ends, Python says nothing
    if hasattr(signal, "pthread_sigmask"):  # started blocked: a Ctrl-C that came while it loaded ends it now
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def evaluate_part(task: tuple[EvaluationJob, list[int]],
                  on_progress: Callable[[float], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Some episodes of one job of :func:`evaluate_all` (:func:`~stewart_gym.evaluation.evaluation_part`); in a
    worker process the policy is loaded there, and progress goes to the parent's queue."""
    from stewart_gym.evaluation import evaluation_part
    from stewart_gym.registry import load_for_evaluation

    job, indices = task
    _, policy, _ = load_for_evaluation(job.spec, job.env_id, job.geometry, job.estimator)
    if on_progress is None and _REPORTS:
        on_progress = _REPORTS[0].put
    return evaluation_part(job.env_id, policy, indices, job.episodes, job.seed, job.randomize,
                           env_kwargs=job.env_kwargs, on_progress=on_progress)  # fmt: skip


#: What ``demo`` compares: the learned policies shipped for the build (the best first; its episode is the GIF)
#: and the two strongest classical controllers, each behind the observer it was tuned behind.
DEMO_LEARNED = ("shipped-residual", "shipped")
DEMO_CLASSICAL = ("pid-kalman", "lqr")


def demo_policies(env_id: str, geometry: str | None) -> list[str]:
    """The ``--policy`` names ``demo`` evaluates on ``geometry``: the shipped learned policies that exist for it
    (``shipped`` always: where none exists, loading it says so), then :data:`DEMO_CLASSICAL`."""
    from stewart_gym.registry import DEFAULT_GEOMETRY, SHIPPED_TABLES

    key = (env_id, geometry or DEFAULT_GEOMETRY)
    learned = [name for name in DEMO_LEARNED if name == "shipped" or key in SHIPPED_TABLES[name]]
    return [*learned, *DEMO_CLASSICAL]


def in_world(env_kwargs: dict, source: Any, backend: str | None, sensor: str | None) -> dict:
    """``env_kwargs`` with the physics engine and the ball sensor asked for, else the ones ``source`` (a resolved
    policy) was trained with (not a :data:`TRAINING_BACKENDS` engine), else the env's defaults (PyBullet, the
    touch panel)."""
    chosen = {"backend": backend or trained_world(source, "backend"), "sensor": sensor or trained_world(source, "sensor")}
    return {**env_kwargs, **{k: v for k, v in chosen.items() if v is not None}}


def trained_world(source: Any, key: str) -> str | None:
    """The physics engine (``key`` ``"backend"``) or ball sensor (``"sensor"``) a resolved policy (``source``) was
    trained with and is evaluated in unless told otherwise: None where it names none, or where its engine is one for
    training only (:data:`TRAINING_BACKENDS`)."""
    value = source.env_kwargs.get(key)
    return None if key == "backend" and value in TRAINING_BACKENDS else value


def world(env_id: str, env_kwargs: dict) -> dict[str, str]:
    """Where an evaluation ran: the env id, the build (``geometry``: a preset's name or the TOML file), the
    physics engine (the one ``auto`` picks where none was asked for), the ball sensor and, where the target
    moves, its trajectory (for ``--json`` and the line above a table)."""
    from stewart_gym.presets import load_geometry
    from stewart_gym.sim.engines import default_backend

    geometry = env_kwargs.get("geometry", "servo-hexapod")
    name = load_geometry(geometry).name
    given = geometry if isinstance(geometry, (str, Path)) else name  # (a held geometry, a bundle's: by its name)
    out = {"env_id": env_id, "geometry": str(given), "geometry_name": name,
           **{k: str(env_kwargs.get(k, v)) for k, v in WORLD_DEFAULTS.items()}}  # fmt: skip
    if "backend" not in env_kwargs or env_kwargs["backend"] == "auto":
        out["backend"] = default_backend()
    if env_id in trajectory_env_ids():
        out["trajectory"] = str(env_kwargs.get("trajectory", "circle"))
    if env_kwargs.get("twin") is not None:
        out["twin"] = "given"  # its tables: the commands that read the file name it
    return out


def world_line(where: dict[str, str]) -> str:
    """:func:`world` as words: ``StewartBallBalance-v0 on my-build (runs/a/geometry.toml), pybullet, sensor panel``."""
    build = where["geometry_name"] + (f" ({where['geometry']})" if where["geometry"] != where["geometry_name"] else "")
    moving = f", trajectory {where['trajectory']}" if "trajectory" in where else ""
    twin = ", the twin's physics" if "twin" in where else ""
    return f"{where['env_id']} on {build}, {where['backend']}, sensor {where['sensor']}{moving}{twin}"


def check_can_render(backend: str | None) -> None:
    """Before long work, :class:`ConfigError` where no GIF can be drawn: the batched backend draws nothing, and
    MuJoCo renders with OpenGL, which a headless machine may lack."""
    if backend == "batched":
        raise ConfigError("the batched backend does not render a GIF; use backend pybullet or mujoco to watch")
    if backend == "mujoco":
        from stewart_gym.sim.mujoco_sim import check_rendering

        check_rendering()


def episode_figures(env_id: str, policy: object, env_kwargs: dict, seed: int, randomize: bool, gif: Path | None,
                     plot: Path | None, title: str) -> None:  # fmt: skip
    """Run one episode from the standard offset (100 mm, less on a small plate); write its GIF and/or its
    ball-path and pulse-width plot, titled ``title`` (the policy and where it ran)."""
    import gymnasium as gym

    from stewart_gym.evaluation import GIF_FPS, plot_episode, run_episode, settling_offset, write_gif

    env = gym.make(env_id, randomize=randomize, render_mode="rgb_array" if gif else None, **env_kwargs)
    try:
        opts = {"ball_position": (settling_offset(env), 0.0), "ball_velocity": (0.0, 0.0)}
        every = max(1, round(1.0 / (GIF_FPS * env.unwrapped.sim.dt))) if gif else 0  # the frames the GIF shows
        log = run_episode(env, policy, seed, None if env.unwrapped.task.moving_target else opts, frame_every=every)
    finally:
        env.close()
    if gif:
        target = "target: the plate's centre" if not env.unwrapped.task.moving_target else "target: moving"
        frame_dt = log.dt * log.frame_every
        write_gif(log.frames, gif, fps=1.0 / frame_dt, dt=frame_dt, caption=target)
    if plot:
        plot_episode(log, plot, title)


def compare_setup(policies: list[str], env_id: str | None = None, geometry: str | None = None,
                  backend: str | None = None, sensor: str | None = None,
                  trajectory: str | None = None, twin: dict | None = None) -> tuple[str, str, dict[str, dict]]:  # fmt: skip
    """Before any episode: the env id, the build and each policy's env keywords for :func:`compare`, every
    policy loaded once (a bad one is a :class:`ConfigError` or :class:`~stewart_gym.errors.PolicyError`). The
    task is ``env_id``, else the one the trained policies given by path were trained for (which must agree), else
    the first policy's; the build is ``geometry``, else the one a trained policy given by path was trained for
    (the named ones adapt to both); the physics engine and the sensor are ``backend`` and ``sensor``, else the
    ones the policies were trained with, which must then agree; ``twin`` (a twin's tables) is the platform they
    all run on."""
    from stewart_gym.control import CLASSICAL_KINDS
    from stewart_gym.registry import CLASSICAL, DEFAULT_GEOMETRY, SHIPPED_TABLES, load_for_evaluation, resolve_policy

    sources = {spec: resolve_policy(spec, env_id) for spec in policies}
    own = [s for s in sources.values() if s.spec not in (*SHIPPED_TABLES, *CLASSICAL) and s.kind in ("sb3", "ensemble",
                                                                                                     "bundle")]
    if env_id is None:  # the trained networks' task (the named policies adapt to it), else the first policy's
        tasks = {s.spec: s.env_id for s in own}
        if len(set(tasks.values())) > 1:
            named = ", ".join(f"{spec} for {task}" for spec, task in tasks.items())
            raise ConfigError(f"the policies were trained for different tasks ({named}): say which to compare them "
                              f"on, e.g. --env {next(iter(tasks.values()))}")  # fmt: skip
        env_id = next(iter(tasks.values()), sources[policies[0]].env_id)
    geometry = geometry or (own[0].geometry if own else DEFAULT_GEOMETRY)
    chosen = {"backend": backend, "sensor": sensor}
    for key in chosen:  # a trained network's world, else the env's default; a classical controller has none
        trained = {spec: trained_world(s, key) or WORLD_DEFAULTS[key] for spec, s in sources.items()
                   if trained_world(s, key) is not None or s.kind not in CLASSICAL_KINDS}  # fmt: skip
        if chosen[key] is None and len(set(trained.values())) > 1:
            named = ", ".join(f"{spec} with {value}" for spec, value in trained.items())
            raise ConfigError(f"the policies were trained with different {key}s ({named}): say which to compare "
                              f"them with, e.g. --{key} {next(iter(trained.values()))}")  # fmt: skip
        chosen[key] = chosen[key] or next(iter(trained.values()), None)
    check_trajectory(env_id, trajectory)
    env_kwargs = {}
    for spec in policies:
        source, _, kwargs = load_for_evaluation(spec, env_id, geometry)
        env_kwargs[spec] = resolve_world(source, kwargs, env_id, chosen["backend"], chosen["sensor"],
                                         trajectory).env_kwargs  # fmt: skip
        if twin is not None:
            env_kwargs[spec]["twin"] = twin
    return env_id, geometry, env_kwargs




def compare(policies: list[str], env_id: str | None = None, episodes: int = 100, seed: int = 0, randomize: bool = True,
            geometry: str | None = None, backend: str | None = None, sensor: str | None = None,
            trajectory: str | None = None, workers: int | None = None,
            on_progress: Callable[[float], None] | None = None,
            twin: dict | None = None) -> tuple[dict[str, dict], list[dict]]:  # fmt: skip
    """Evaluate ``policies`` on the same seeded episodes (:func:`compare_setup`, :func:`evaluate_all`) and pair the
    first with each of the others (:func:`~stewart_gym.evaluation.paired_rows`): (figures by policy, paired
    rows)."""
    from stewart_gym.evaluation import paired_rows

    env, build, env_kwargs = compare_setup(policies, env_id, geometry, backend, sensor, trajectory, twin)
    processes, parts = process_plan(workers, len(policies), episodes)
    jobs = [EvaluationJob(spec, env, build, None, env_kwargs[spec], episodes, seed, randomize) for spec in policies]
    results = dict(zip(policies, evaluate_all(jobs, parts, processes, on_progress)))
    return results, paired_rows(results, policies[0])
