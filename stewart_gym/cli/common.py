"""What every ``stewart-gym`` subcommand shares: argument types that check values at the edge, an argument
parser whose mistakes are one ``error:`` line, output paths checked before long work, and the error handling
of :func:`run`.

Exit codes (:data:`EXIT_CODES`; the docs and ``stewart-gym --help`` show them):

* 0: the command did what was asked;
* 1: a user mistake (bad option, missing or malformed file), or a result that failed: an unreachable pose,
  a trajectory with unreachable samples, a deploy run that could not keep its rate;
* 2: a device failure (serial port missing, unplugged, not answering);
* 128 + N: stopped by signal N: 130 Ctrl-C (SIGINT), 143 SIGTERM, 129 SIGHUP. A deploy run stopped so drives the
  servos home and prints its summary first.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import math
import os
import re
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Iterator
from typing import Any, NoReturn

import numpy as np

from stewart_gym.errors import ConfigError, DeviceFailure, StewartGymError, Stopped
from stewart_gym.outputs import output_dir, output_file
from stewart_gym.progress import line_interval_s

__all__ = ["EXIT_DEVICE", "EXIT_FAILED", "EXIT_INTERRUPTED", "EXIT_OK", "MAX_SEED", "Parser", "bounded_float",
           "finite_float", "int_at_least", "interrupted", "json_safe", "output_dir", "output_file", "positive_float", "run",
           "stop_signals"]  # fmt: skip

EXIT_OK, EXIT_FAILED, EXIT_DEVICE, EXIT_INTERRUPTED = 0, 1, 2, 130
#: The largest seed a command takes (NumPy's legacy seeding, which Stable-Baselines3 calls, takes 32 bits).
MAX_SEED = 2**31 - 1
#: Optional dependencies and the install extra that brings each (pyproject.toml).
EXTRA_OF_MODULE = {"gymnasium": "sim", "pybullet": "sim", "pybullet_utils": "sim", "imageio": "sim", "torch": "train",
                   "stable_baselines3": "train", "sb3_contrib": "train", "tensorboard": "train", "yaml": "train",
                   "onnx": "train", "onnxscript": "train", "moviepy": "video",
                   "tqdm": "train", "rich": "train", "onnxruntime": "deploy", "serial": "deploy",
                   "mujoco": "mujoco", "cv2": "camera", "ray": "cluster", "optuna": "cluster"}  # fmt: skip
#: What each exit code means (the --help epilog and the docs' table are made from it).
EXIT_CODES = {
    EXIT_OK: "the command did what was asked",
    EXIT_FAILED: "a user error (bad option, missing or malformed file, missing optional dependency) or a failed "
                 "result: an unreachable pose (`ik`, `render`), a trajectory with an unreachable sample, a deploy run "
                 "that missed more than 5 % of its deadlines, never got a usable action from its policy, or had no "
                 "fresh valid sensor reading on most of its ticks",
    EXIT_DEVICE: "a device failure: the serial port is missing, unplugged, not answering or not reading",
    EXIT_INTERRUPTED: "stopped by Ctrl-C (SIGINT); in general 128 + N for signal N: 143 SIGTERM, 129 SIGHUP (deploy "
                      "drives the servos home and prints its summary first)",
}  # fmt: skip
#: The signals that stop a command as Ctrl-C does (:func:`stop_signals`), by name.
STOP_SIGNALS = {name: getattr(signal, name) for name in ("SIGTERM", "SIGHUP", "SIGBREAK")  # (SIGBREAK: Windows'
                if hasattr(signal, name)}  # Ctrl-Break, and its console window closing)
EXIT_CODES_HELP = "exit codes: " + "; ".join(f"{code} {text.replace('`', '')}" for code, text in EXIT_CODES.items())


def exit_code_table() -> str:
    """The exit codes as a Markdown table."""
    return "\n".join(["| exit code | meaning |", "|---|---|"] + [f"| {c} | {t} |" for c, t in EXIT_CODES.items()])


class _DefaultsShown(argparse.HelpFormatter):
    """Each option's help ends with its default, where it has one (not None or False) that the help does not
    give already."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (action.default is None or action.default is False or action.default == argparse.SUPPRESS
                or "default" in text or not action.option_strings):  # fmt: skip
            return text
        return f"{text} (default: %(default)s)" if text else "default: %(default)s"


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line, ``error: …``, and exit code 1, and which takes a
    negative number as users type it (``-1e-3``, ``-.5``, ``-inf``) for a value, not an option."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # argparse's own test of a negative number knows no exponent: "ik -1e-3 0 0 0 0 0" lacked an argument
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^-(inf|nan)$", re.IGNORECASE)

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"error: {self.prog}: {message} (see {self.prog} --help)\n")
        sys.exit(EXIT_FAILED)

    @classmethod
    def for_script(cls, docstring: str, **kwargs: Any) -> Parser:
        """A script's parser, described by its docstring's first paragraph as plain text (reST's ````code````
        marks dropped); its help gives each option's default."""
        text = re.sub(r"``([^`]+)``", r"\1", docstring.split("\n\n")[0].strip())
        kwargs.setdefault("formatter_class", _DefaultsShown)
        return cls(description=text, **kwargs)

    def arguments(self) -> list[argparse.Action]:
        """Every argument this parser takes, in the order they were added (``-h`` and the subcommands included)."""
        return list(self._actions)

    def subcommands(self) -> dict[str, Parser]:
        """The subcommands' parsers by name, in the order ``--help`` lists them (none for a subcommand's own)."""
        return next((dict(a.choices) for a in self._actions if a.nargs == argparse.PARSER), {})


# ------------------------------------------------------------ argument types
def finite_float(text: str) -> float:
    """A float that is neither NaN nor infinite."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return v


def positive_float(text: str) -> float:
    """A finite float > 0."""
    v = finite_float(text)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be greater than 0")
    return v


def bounded_float(lo: float, hi: float, *, lo_open: bool = False) -> Callable[[str], float]:
    """A finite float in [lo, hi] (or (lo, hi] with ``lo_open``)."""

    def parse(text: str) -> float:
        v = finite_float(text)
        if v > hi or v < lo or (lo_open and v == lo):
            raise argparse.ArgumentTypeError(f"{text!r} must be in {'(' if lo_open else '['}{lo:g}, {hi:g}]")
        return v

    parse.__name__ = "number"
    return parse


def int_at_least(lo: int, hi: int | None = None) -> Callable[[str], int]:
    """An integer ≥ ``lo`` (and ≤ ``hi``)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            try:  # a whole number written as a float ("1e12", "20.0") is read as one, then its range checked
                number = float(text)
            except ValueError:
                number = math.nan
            if not (math.isfinite(number) and number.is_integer()):
                raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
            v = int(number)
        if v < lo or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"{text!r} must be at least {lo}" + (f" and at most {hi}" if hi else ""))
        return v

    parse.__name__ = "integer"
    return parse


def geometry_text(text: str) -> str:
    """A ``--geometry``: a preset name or a file, not empty (an empty path is the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty: give a preset name or a TOML file")
    return text


geometry_text.__name__ = "geometry"


# -------------------------------------------------------------------- run
@contextlib.contextmanager
def stop_signals() -> Iterator[None]:
    """While in the block, SIGTERM and SIGHUP raise :class:`~stewart_gym.errors.Stopped` (a
    ``KeyboardInterrupt``) in the main thread, as Ctrl-C raises ``KeyboardInterrupt``: whatever cleans up after
    Ctrl-C (deploy's drive home) cleans up after them too. Ctrl-C (SIGINT) raises ``KeyboardInterrupt`` even
    where the process was started with it ignored (a background job of a script, a parent that ignores it):
    a signal to stop is never lost while the servos move. The handlers before are restored after. Outside the
    main thread (where Python allows no handlers) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def raise_stopped(signum: int, frame: object) -> None:
        raise Stopped(signum, signal.Signals(signum).name)

    before = {num: signal.signal(num, raise_stopped) for num in STOP_SIGNALS.values()}
    before[signal.SIGINT] = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        for num, handler in before.items():
            signal.signal(num, handler)


def interrupted(exc: KeyboardInterrupt) -> int:
    """Say that a command was stopped by a signal (one ``error:`` line); its exit code, 128 + the signal's number."""
    signum = int(getattr(exc, "signum", signal.SIGINT))
    name = getattr(exc, "name", "Ctrl-C (SIGINT)")
    print(f"error: stopped by {name} before the command finished", file=sys.stderr)
    return 128 + signum


def run(func: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """Call a subcommand; a user's mistake or a device failure becomes one ``error:`` line and an exit code.

    With ``--debug`` every error keeps its traceback. Errors that are not the
    user's (bugs) always do. A stop signal (Ctrl-C, SIGTERM, SIGHUP: :func:`stop_signals`) is one line and exit
    code 128 + its number.
    """
    debug = bool(getattr(args, "debug", False))
    try:
        return _call(func, args)
    except KeyboardInterrupt as exc:
        if debug:
            raise
        return interrupted(exc)
    except BrokenPipeError:  # the output was piped into a program that stopped reading (head): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_FAILED
    except ModuleNotFoundError as exc:
        extra = EXTRA_OF_MODULE.get((exc.name or "").split(".")[0])
        if extra is None or debug:
            raise
        print(f"error: this needs {exc.name}, which is not installed: pip install 'stewart_gym[{extra}]'",
              file=sys.stderr)  # fmt: skip
        return EXIT_FAILED
    except (StewartGymError, OSError, UnicodeDecodeError) as exc:
        if debug:
            traceback.print_exc()
        print(f"error: {describe(exc)}", file=sys.stderr)
        is_device = isinstance(exc, DeviceFailure) or _is_serial_error(exc)
        return EXIT_DEVICE if is_device else EXIT_FAILED


def _call(func: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """Call a subcommand; a stop signal that a library turned into its own error is raised as the stop again.

    A signal handler's exception can surface inside a library's C code, which then reports its own failure
    (a C extension's import says ``ImportError: initialization failed``) with the stop as its cause."""
    try:
        line_interval_s()
    except ValueError as exc:  # a bad $STEWART_GYM_PROGRESS_S: the user's mistake, before any work
        raise ConfigError(str(exc)) from None
    try:
        return int(func(args))
    except Exception as exc:
        stop = stop_behind(exc)
        if stop is None:
            raise
        raise stop from exc


def stop_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The stop signal (Ctrl-C, SIGTERM, SIGHUP) among an exception's causes and contexts, or None."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None


def describe(exc: BaseException) -> str:
    """One line for an error: the package's own message, or what an OS error says about which file."""
    if isinstance(exc, OSError) and not _is_serial_error(exc) and exc.strerror:
        name = f"{exc.filename}: " if exc.filename else ""
        hint = {FileNotFoundError: "check the path", PermissionError: "check the permissions",
                IsADirectoryError: "give a file, not a folder",
                NotADirectoryError: "a part of the path is a file"}.get(type(exc), "")  # fmt: skip
        hint = hint or {errno.ENOSPC: "free some space, or write elsewhere", errno.EDQUOT: "free some space, or "
                        "write elsewhere", errno.EROFS: "write elsewhere", errno.ENAMETOOLONG: "give a shorter "
                        "name"}.get(exc.errno or 0, "")  # fmt: skip
        return f"{name}{exc.strerror.lower()}" + (f" ({hint})" if hint else "")
    if isinstance(exc, UnicodeDecodeError):
        return "a file that should be text is not (binary or not UTF-8)"
    text = " ".join(str(exc).split())  # one line
    return text or type(exc).__name__


def _is_serial_error(exc: BaseException) -> bool:
    return type(exc).__module__.startswith("serial")


def json_safe(v: Any) -> Any:
    """Numpy values to plain Python, NaN/inf to None: strict JSON."""
    if isinstance(v, dict):
        return {k: json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [json_safe(x) for x in v]
    if isinstance(v, np.ndarray):
        return json_safe(v.tolist())
    if isinstance(v, (np.floating, float)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def add_backend(parser: argparse.ArgumentParser, text: str) -> None:
    """``--backend pybullet|mujoco|batched``."""
    from stewart_gym.sim.engines import BACKEND_NAMES

    parser.add_argument("--backend", choices=BACKEND_NAMES, help=text)


def add_sensor(parser: argparse.ArgumentParser, text: str) -> None:
    """``--sensor panel|camera|pixy2|webcam30|global90`` (the env's ball sensor model)."""
    from stewart_gym.camera import CAMERA_PRESETS

    parser.add_argument("--sensor", choices=("panel", "camera", *CAMERA_PRESETS), help=text)


def add_estimator(parser: argparse.ArgumentParser, text: str) -> None:
    """``--estimator lowpass|kalman`` (how the observer estimates the ball's state)."""
    from stewart_gym.sensing import ESTIMATORS

    parser.add_argument("--estimator", choices=ESTIMATORS, help=text)


def add_geometry(parser: argparse.ArgumentParser, default: str = "servo-hexapod") -> None:
    """``--geometry NAME|FILE``."""
    from stewart_gym.presets import preset_names

    parser.add_argument("--geometry", default=default, help=f"preset ({', '.join(preset_names())}) or TOML file")


def add_twin(parser: argparse.ArgumentParser, text: str) -> None:
    """``--twin FILE`` (a platform's twin, :mod:`stewart_gym.sim.twin`)."""
    parser.add_argument("--twin", metavar="FILE", help=text)


def twin_tables(path: str | None) -> dict | None:
    """The twin file's tables, checked (an ``error:`` line naming the file and key), as the env takes them; None
    without ``--twin``."""
    if path is None:
        return None
    from stewart_gym.sim.twin import load_twin

    return load_twin(path).to_mapping()
