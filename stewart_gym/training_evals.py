"""The evaluations during a training run: in the training's own process, or in a second process so that the
training goes on while each policy is evaluated.

An evaluator takes snapshots of the policy being trained (:meth:`submit`) and gives back an
:class:`Evaluation` of each (:meth:`results`), in the order they were taken. Each evaluation plays
``n_episodes`` deterministic episodes with SB3's ``evaluate_policy`` on one evaluation env, built once and seeded
once, so that a run's evaluations play the same episodes in either process: the results are the same.

- :class:`InProcessEvaluator` evaluates at once, in the training's process, as SB3's ``EvalCallback`` does.
- :class:`BackgroundEvaluator` sends each snapshot (the model's zip and the observation statistics) to one worker
  process, which builds its own evaluation env. On a machine with two cores the
  training does not wait for its evaluations.
"""

from __future__ import annotations

import io
import multiprocessing
import multiprocessing.context
import os
import pickle
import queue
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv, VecNormalize, sync_envs_normalization

__all__ = ["BackgroundEvaluator", "Evaluation", "InProcessEvaluator", "play", "worker_start_method"]

#: s between checks that the worker process is still alive while waiting for its results
_POLL_S = 0.5
#: bytes: the longest path a Unix socket may have (``sun_path``: 108 with its terminating NUL)
_SOCKET_PATH_MAX = 107
#: What a forkserver's socket adds to the temporary directory: ``/pymp-XXXXXXXX/listener-XXXXXXXX``.
_FORKSERVER_SOCKET = len("/pymp-12345678/listener-12345678")


def worker_start_method() -> str:
    """How the worker processes of a training start (the evaluation worker, ``--vec-env subproc``'s envs):
    ``"forkserver"`` where the platform has it, a warm server from which each worker starts in about 0.1 s; else
    ``"spawn"``. The server listens on a Unix socket in the temporary directory (``$TMPDIR``), whose path may not
    be longer than 107 bytes: under a longer temporary directory the workers are spawned instead, which start
    more slowly but work."""
    if "forkserver" not in multiprocessing.get_all_start_methods():  # Windows
        return "spawn"
    if len(os.fsencode(tempfile.gettempdir())) + _FORKSERVER_SOCKET > _SOCKET_PATH_MAX:
        return "spawn"
    return "forkserver"


@dataclass(frozen=True)
class Evaluation:
    """One evaluation of the policy as it was after ``timesteps`` env steps."""

    timesteps: int
    episode_rewards: list[float]
    episode_lengths: list[int]
    successes: list[bool]  # each episode's final ``info["is_success"]``, where the env gives one


def play(model: BaseAlgorithm, env: VecEnv, n_episodes: int) -> tuple[list[float], list[int], list[bool]]:
    """``n_episodes`` deterministic episodes of ``model`` on ``env``: their rewards, lengths and successes."""
    successes: list[bool] = []

    def log_success(locals_: dict[str, Any], _globals: dict[str, Any]) -> None:
        if locals_["done"] and locals_["info"].get("is_success") is not None:
            successes.append(bool(locals_["info"]["is_success"]))

    rewards, lengths = evaluate_policy(model, env, n_eval_episodes=n_episodes, deterministic=True,
                                       return_episode_rewards=True, callback=log_success)  # fmt: skip
    return [float(r) for r in rewards], [int(n) for n in lengths], successes


class InProcessEvaluator:
    """Evaluations in the training's process, each when its snapshot is taken.

    Args:
        env: The evaluation env (a :class:`VecNormalize` that does not update, if the training env normalises).
        n_episodes: Episodes per evaluation.
    """

    def __init__(self, env: VecEnv, n_episodes: int) -> None:
        self.env, self.n_episodes = env, int(n_episodes)
        self._done: list[Evaluation] = []

    def start(self) -> None:
        """Nothing to start: the evaluations run in this process."""

    def submit(self, timesteps: int, model: BaseAlgorithm, zipped: bytes) -> None:
        """Evaluate ``model`` now, with the training env's observation statistics (``zipped``, the model as
        saved, is not needed here)."""
        if model.get_vec_normalize_env() is not None:
            sync_envs_normalization(model.get_env(), self.env)
        self._done.append(Evaluation(int(timesteps), *play(model, self.env, self.n_episodes)))

    def results(self, wait: bool = False) -> list[Evaluation]:
        """The evaluations not yet returned (all of them are done)."""
        done, self._done = self._done, []
        return done

    def close(self) -> None:
        self.env.close()


class BackgroundEvaluator:
    """Evaluations in one worker process, while the training goes on.

    Args:
        make_env: Builds the evaluation env in the worker (picklable, e.g. a ``functools.partial`` of a
            module-level function); seeded there once.
        algo: The model's class, to load each snapshot.
        n_episodes: Episodes per evaluation.
        normalize: ``VecNormalize`` keywords if the training env normalises its observations, else None.
    """

    def __init__(self, make_env: Callable[[], VecEnv], algo: type[BaseAlgorithm], n_episodes: int,
                 normalize: dict[str, Any] | None = None) -> None:  # fmt: skip
        self._spec = (make_env, algo, int(n_episodes), normalize)
        self._process: multiprocessing.process.BaseProcess | None = None
        self._tasks: Any = None
        self._answers: Any = None
        self._pending = 0

    @property
    def pid(self) -> int | None:
        """The worker's process id (None before it starts)."""
        return None if self._process is None else self._process.pid

    def start(self) -> None:
        """Start the worker now, so that it is ready for the first snapshot (else :meth:`submit` starts it)."""
        if self._process is not None:
            return
        method = worker_start_method()
        context: multiprocessing.context.BaseContext = multiprocessing.get_context(method)
        if method == "forkserver":
            context.set_forkserver_preload(["stewart_gym.training"])  # a warm server: each worker starts in ~0.1 s
        self._tasks, self._answers = context.Queue(), context.Queue()
        self._process = context.Process(target=_serve, args=(*self._spec, self._tasks, self._answers, os.getpid()),
                                        daemon=True, name="stewart-gym evaluations")  # fmt: skip
        self._process.start()

    def submit(self, timesteps: int, model: BaseAlgorithm, zipped: bytes) -> None:
        """Send the policy as it is now (``zipped``: ``model`` saved now, as ``model.save`` writes it) and the
        training env's observation statistics to be evaluated."""
        self.start()
        norm = model.get_vec_normalize_env()
        statistics = None if norm is None else pickle.dumps(norm.obs_rms)
        self._tasks.put((int(timesteps), zipped, statistics))
        self._pending += 1

    def results(self, wait: bool = False) -> list[Evaluation]:
        """The evaluations that have come back since the last call; with ``wait``, all that were sent. Raises
        :class:`RuntimeError` if the worker failed or died."""
        done = []
        while self._pending:
            try:
                answer = self._answers.get(timeout=_POLL_S) if wait else self._answers.get_nowait()
            except queue.Empty:
                if not wait:
                    break
                if self._process is not None and not self._process.is_alive():
                    raise RuntimeError(f"the evaluation process ended (exit code {self._process.exitcode}) with "
                                       f"{self._pending} evaluation(s) outstanding") from None  # fmt: skip
                continue
            self._pending -= 1
            if isinstance(answer, str):
                raise RuntimeError(f"the evaluation process failed: {answer}")
            done.append(answer)
        return done

    def close(self) -> None:
        """Stop the worker (it finishes nothing outstanding), and let this process exit without the snapshots it
        did not take."""
        if self._process is None:
            return
        if self._process.is_alive():
            self._tasks.put(None)
            self._process.join(timeout=1.0)  # an evaluation under way is not waited for
        if self._process.is_alive():
            self._process.kill()
            self._process.join()
        for channel in (self._tasks, self._answers):  # a snapshot no one will read must not hold up this process's exit
            channel.cancel_join_thread()
            channel.close()
        self._process = None


def _serve(make_env: Callable[[], VecEnv], algo: type[BaseAlgorithm], n_episodes: int,
           normalize: dict[str, Any] | None, tasks: Any, answers: Any, owner: int) -> None:  # fmt: skip
    """The worker: evaluate each (timesteps, model zip, observation statistics) from ``tasks`` until None, or
    until the ``owner`` process is gone (killed without the chance to stop it)."""
    import torch

    torch.set_num_threads(1)  # one core for the evaluations, the other for the training
    try:
        env: VecEnv = make_env()
        if normalize is not None:
            env = VecNormalize(env, training=False, norm_reward=False, **normalize)
        while True:
            try:
                task = tasks.get(timeout=_POLL_S)
            except queue.Empty:
                if _alive(owner):
                    continue
                break
            if task is None:
                break
            timesteps, zipped, statistics = task
            model = algo.load(io.BytesIO(zipped), device="cpu")
            if statistics is not None:
                env.obs_rms = pickle.loads(statistics)
            answers.put(Evaluation(timesteps, *play(model, env, n_episodes)))
        env.close()
    except BaseException as exc:  # noqa: BLE001 - whatever it is, the training process reports it
        answers.put(f"{type(exc).__name__}: {exc}")


def _alive(pid: int) -> bool:
    """Whether the process ``pid`` is still there. On Windows, where ``os.kill(pid, 0)`` would send a Ctrl-C to the
    whole console (0 is ``CTRL_C_EVENT`` there), the parent process multiprocessing knows answers instead."""
    if sys.platform == "win32":
        parent = multiprocessing.parent_process()
        return parent is None or parent.pid != pid or parent.is_alive()
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
