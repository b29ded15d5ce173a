"""The batched vector env split over worker processes, one core each: ``gym.make_vec(id, num_envs, vectorization_mode=
"vector_entry_point", workers=k)``.

:class:`SplitVectorEnv` splits the copies into ``workers`` shares, as equal as can be. This process steps the first
share itself, a :class:`~stewart_gym.envs.vector.StewartBallVectorEnv`, while each of ``workers`` − 1 worker
processes steps one of the others: every step sends each worker its actions, steps the first share meanwhile, and
gathers what the workers return: their shares' arrays (:meth:`~stewart_gym.envs.vector.ArrayVectorEnv.step_arrays`),
which this process joins and batches once as Gymnasium batches infos (:class:`~stewart_gym.envs.vector.ArrayVectorEnv`).
Copy i is exactly copy i of one ``StewartBallVectorEnv`` of all the copies, seeded alike (copy i with ``seed + i``),
so the split changes the speed, not the numbers.

A worker is a fresh Python running ``python -m stewart_gym.envs.split_vector FD_IN FD_OUT`` (a subprocess, not a fork
of the caller, so that it neither copies the caller's threads nor imports the caller's script again: no ``if
__name__ == "__main__"`` is needed, but a task must be importable, not defined in the script itself); it starts in
about a second. Messages go as pickles over two pipes (a worker's widened, where Linux allows, to hold a step's
answer). A worker that fails (its env raising, or the process dying) makes the call raise
:class:`~stewart_gym.errors.ConfigError` with its message; :meth:`close` ends the workers (and kills any that do not
end within 10 s).
"""
from __future__ import annotations

import os
import pickle
import subprocess
import sys
import traceback
from multiprocessing.connection import Connection
from typing import Any

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]

import numpy as np
from gymnasium.vector import VectorEnv
from gymnasium.vector.utils import batch_space

from stewart_gym.envs.vector import (
    ArrayVectorEnv,
    Finals,
    StewartBallVectorEnv,
    check_num_envs,
    copy_seeds,
    whole_number,
)
from stewart_gym.errors import ConfigError

__all__ = ["SplitVectorEnv", "WorkerTraceback", "batched_vector_env"]

#: The most worker processes one split env starts.
MAX_WORKERS = 256


def batched_vector_env(num_envs: int = 1, *, workers: int = 1, **kwargs: Any) -> VectorEnv:
    """The batched vector env (Gymnasium's ``vector_entry_point``): one :class:`StewartBallVectorEnv` in this
    process (``workers=1``, the default), or a :class:`SplitVectorEnv` over ``workers`` processes."""
    if not whole_number(workers, 1, MAX_WORKERS):
        raise ConfigError(f"workers must be a whole number from 1 to {MAX_WORKERS}, got {workers!r}")
    if workers > 1 and sys.platform == "win32":
        raise ConfigError("workers > 1 joins its worker processes by inherited pipes, which Windows cannot pass: "
                          "leave workers out (one process), or run on Linux, macOS or WSL")  # fmt: skip
    if workers == 1:
        return StewartBallVectorEnv(num_envs, **kwargs)
    return SplitVectorEnv(num_envs, workers=int(workers), **kwargs)


def _failure(exc: BaseException) -> tuple[BaseException | None, str]:
    """What a worker sends of an error: the exception itself where it pickles (the caller raises it as one
    process's env would), and its traceback's text."""
    text = traceback.format_exc()
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:  # noqa: BLE001 - an exception that does not travel: its text does
        return None, text
    return exc, text


class WorkerTraceback(Exception):
    """The traceback of an error raised in a worker process, as the cause of the error the caller raises."""


def _work(inbox: Connection, conn: Connection) -> None:  # pragma: no cover - a child process
    """A worker: make its share of the copies (the first message: its ``num_envs`` and keywords), then answer
    ``(command, argument)`` messages from ``inbox`` on ``conn`` until ``close``."""
    try:
        num_envs, kwargs = inbox.recv()
        env = StewartBallVectorEnv(num_envs, **kwargs)
        conn.send(("ok", None))
    except Exception as exc:  # noqa: BLE001 - the parent reports it
        conn.send(("error", _failure(exc)))
        return
    while True:
        try:
            command, argument = inbox.recv()
        except EOFError:  # the parent has gone
            env.close()
            return
        try:
            if command == "reset":
                result: Any = env.reset_arrays(**argument)
            elif command == "step":
                result = env.step_arrays(argument)
            else:  # close
                env.close()
                conn.send(("ok", None))
                return
            conn.send(("ok", result))
        except Exception as exc:  # noqa: BLE001 - the parent reports it
            conn.send(("error", _failure(exc)))


def _columns(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The shares' infos (one array per key, a row per copy) as one: each key's rows in share order."""
    return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}


#: bytes a worker's answer takes per copy of its share, about (its observation, reward, ends and info)
ANSWER_BYTES_PER_COPY = 256
#: bytes of pipe one split env asks for in all, at most: the system counts a user's pipes together (Linux:
#: ``/proc/sys/fs/pipe-user-pages-soft``, 64 MiB by default), and the user's other pipes need their share too
PIPE_BUDGET_BYTES = 4 << 20


def _widen(pipe: int, wanted: int) -> None:
    """Let ``pipe`` hold ``wanted`` bytes where the system allows (Linux's ``F_SETPIPE_SZ``, up to
    ``/proc/sys/fs/pipe-max-size``), so that a worker writes a step's answer at once instead of waiting for the
    caller to read each 64 KiB of it. Elsewhere, or where it is refused, the pipe keeps its size: slower, not
    wrong."""
    setting = getattr(fcntl, "F_SETPIPE_SZ", None) if fcntl is not None else None
    if setting is None or wanted <= 1 << 16:
        return
    try:
        with open("/proc/sys/fs/pipe-max-size") as f:
            fcntl.fcntl(pipe, setting, min(wanted, int(f.read())))
    except (OSError, ValueError):
        pass


class SplitVectorEnv(ArrayVectorEnv):
    """``num_envs`` copies of one env id on ``workers`` processes (their shares as equal as can be): this one, which
    steps the first share itself while the ``workers`` − 1 others step theirs.

    Args:
        num_envs: How many copies in all.
        workers: How many processes (at most ``num_envs``).
        **kwargs: :class:`~stewart_gym.envs.vector.StewartBallVectorEnv`'s keywords, each worker's the same.
    """

    def __init__(self, num_envs: int = 2, *, workers: int = 2, **kwargs: Any) -> None:
        check_num_envs(num_envs)
        if not 1 <= workers <= num_envs:
            raise ConfigError(f"workers must be from 1 to num_envs ({num_envs}), got {workers}")
        for key, value in kwargs.items():  # pickled by name: the workers import it, and cannot import a script
            where = getattr(value, "__module__", None) if callable(value) else type(value).__module__
            if where == "__main__":
                name = getattr(value, "__name__", type(value).__name__)
                raise ConfigError(f"{key}: {name} is defined in the script itself (__main__), which the split vector "
                                  "env's workers cannot import: define it in a module of its own, or use workers=1")
        self.num_envs, self.workers = int(num_envs), int(workers)
        base, extra = divmod(self.num_envs, self.workers)
        self.sizes = [base + (w < extra) for w in range(self.workers)]
        self.starts = np.concatenate([[0], np.cumsum(self.sizes)[:-1]]).astype(int).tolist()
        self._outboxes: list[Connection] = []
        self._conns: list[Connection] = []
        self._processes: list[subprocess.Popen] = []
        environment = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}  # what this one imports
        for size in self.sizes[1:]:
            to_child, from_parent = os.pipe()[::-1]  # (write end, read end)
            to_parent, from_child = os.pipe()[::-1]
            _widen(to_parent, min(ANSWER_BYTES_PER_COPY * size, PIPE_BUDGET_BYTES // (self.workers - 1)))
            process = subprocess.Popen([sys.executable, "-m", "stewart_gym.envs.split_vector", str(from_parent),
                                        str(to_parent)], pass_fds=(from_parent, to_parent), env=environment)  # fmt: skip
            os.close(from_parent)
            os.close(to_parent)
            self._outboxes.append(Connection(to_child, readable=False))
            self._conns.append(Connection(from_child, writable=False))
            self._processes.append(process)
        try:
            self._send([(size, kwargs) for size in self.sizes[1:]])
            #: the first share, stepped in this process
            self.own = StewartBallVectorEnv(self.sizes[0], **kwargs)
            self._gather()
        except Exception:
            self.close_extras(terminate=True)
            raise
        self.single_observation_space = self.own.single_observation_space
        self.single_action_space = self.own.single_action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.metadata = {**self.metadata, "render_fps": self.own.metadata["render_fps"]}
        self.render_mode = None
        self.spec = None

    @property
    def pids(self) -> list[int]:
        """The process ids of the other workers (this process steps the first share)."""
        return [process.pid for process in self._processes]

    def _gather(self) -> list[Any]:
        """Every other worker's answer, in order. The first failure is raised: a worker's error as one process's
        env raises it (its traceback the cause), else :class:`ConfigError`; the env then needs a reset, its
        shares having stepped apart."""
        answers, failure = [], None
        for w, conn in enumerate(self._conns):
            try:
                status, value = conn.recv()
            except (EOFError, OSError):
                code = self._processes[w].poll()
                status, value = "error", (None, f"worker {w} stopped" + (f" (exit code {code})" if code is not None
                                                                          else " answering"))  # fmt: skip
            if status != "ok" and failure is None:
                failure = value
            answers.append(value)
        if failure is not None:
            self.ready = False
            exc, text = failure
            if exc is None:
                raise ConfigError(f"a worker of the split vector env failed: {text.strip()}")
            raise exc from WorkerTraceback(text.strip())
        return answers

    def _own(self, method: Any, *args: Any, **kwargs: Any) -> Any:
        """The first share's ``method(*args, **kwargs)``, the others' being under way: if it raises, their answers
        are read (and dropped) first, so that the next call reads its own."""
        try:
            return method(*args, **kwargs)
        except BaseException:
            try:
                self._gather()
            except ConfigError:
                pass
            raise

    def _send(self, messages: list[Any]) -> None:
        for w, (outbox, message) in enumerate(zip(self._outboxes, messages)):
            try:
                outbox.send(message)
            except (pickle.PicklingError, TypeError, AttributeError) as exc:
                raise ConfigError(f"the split vector env's keywords must pickle to reach its workers: {exc}") from None
            except (BrokenPipeError, OSError):
                raise ConfigError(f"worker {w} of the split vector env has stopped "
                                  f"(exit code {self._processes[w].poll()})") from None  # fmt: skip

    def reset_arrays(self, *, seed: int | list[int | None] | None = None,
                     options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:  # fmt: skip
        self.check_open()
        every = copy_seeds(seed, self.num_envs)
        seeds = [every[start:start + size] for start, size in zip(self.starts, self.sizes)]
        self._send([("reset", {"seed": s, "options": options}) for s in seeds[1:]])
        parts = [self._own(self.own.reset_arrays, seed=seeds[0], options=options), *self._gather()]
        self.ready = True
        return np.concatenate([obs for obs, _ in parts]), _columns([info for _, info in parts])

    def step_arrays(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                         dict[str, np.ndarray], Finals]:  # fmt: skip
        actions = self.checked_actions(actions)  # before any share moves
        self._send([("step", actions[start:start + size]) for start, size in zip(self.starts[1:], self.sizes[1:])])
        parts = [self._own(self.own.step_arrays, actions[:self.sizes[0]]), *self._gather()]
        observations, rewards, terminations, truncations, infos, finals = zip(*parts)
        return (np.concatenate(observations), np.concatenate(rewards), np.concatenate(terminations),
                np.concatenate(truncations), _columns(list(infos)), Finals.joined(finals, self.starts))  # fmt: skip

    def close_extras(self, terminate: bool = False, **kwargs: Any) -> None:
        """End the workers (each closes its env); kill any that do not end within 10 s."""
        try:
            if not terminate:
                for outbox in getattr(self, "_outboxes", []):
                    try:
                        outbox.send(("close", None))
                    except (BrokenPipeError, OSError):
                        pass
            for process in getattr(self, "_processes", []):
                try:
                    process.wait(timeout=0.1 if terminate else 10.0)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait(timeout=5.0)
            for conn in [*getattr(self, "_outboxes", []), *getattr(self, "_conns", [])]:
                try:
                    conn.close()
                except OSError:  # closed already
                    pass
            self._outboxes, self._conns, self._processes = [], [], []
        finally:
            if getattr(self, "own", None) is not None:
                self.own.close()

    def __deepcopy__(self, memo: dict) -> SplitVectorEnv:
        raise TypeError(_NO_COPY)

    def __reduce_ex__(self, protocol: Any) -> Any:
        raise TypeError(_NO_COPY)


#: Why a split vector env is neither copied nor pickled.
_NO_COPY = ("a split vector env (workers > 1) cannot be copied or pickled: its copies live in worker processes; make "
            "a new one, or one with workers=1, which copies")


if __name__ == "__main__":  # pragma: no cover - a worker, started by SplitVectorEnv
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's to handle: it closes the workers, or they
    # read the end of their pipe when it exits
    _work(Connection(int(sys.argv[1]), writable=False), Connection(int(sys.argv[2]), readable=False))
