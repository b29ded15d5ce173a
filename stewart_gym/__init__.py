"""stewart_gym: simulator, RL environments, kinematics and hardware tools for servo Stewart platforms.

Quick start::

    import numpy as np
    from stewart_gym import load_preset, inverse_kinematics, ServoCalibration

    geo = load_preset("servo-hexapod")
    ik = inverse_kinematics(geo, np.array([0.01, 0, 0, 0, np.radians(5), 0]))
    pulses = ServoCalibration.default(geo).pulse_widths(ik.servo_angles)

``import stewart_gym`` registers the environments with Gymnasium (when it is installed) and loads the names
below when they are first used, so that the command line starts quickly and handles Ctrl-C from its first
moments.
"""

import signal as _signal
import sys as _sys
import threading as _threading

#: The stop signals (Ctrl-C's SIGINT) that came while this package loaded in a process that started with SIGINT
#: ignored, as a background job of a script does: the command line stops for them as soon as it runs
#: (:func:`stewart_gym.cli.main`); in any other program they stay ignored, as the process asked.
SIGNALS_WHILE_LOADING: list[int] = []
#: Whether this process started with SIGINT ignored (read as the package starts loading, in the main thread).
SIGINT_IGNORED_AT_START = (_threading.current_thread() is _threading.main_thread()
                           and _signal.getsignal(_signal.SIGINT) is _signal.SIG_IGN)  # fmt: skip


def _as_command() -> bool:
    """Whether this process is the ``stewart-gym`` command: its script, or ``python -m stewart_gym`` (not another
    module of the package run with ``-m``, such as a vector env's worker)."""
    return is_command(_sys.argv[0] if _sys.argv else "", list(getattr(_sys, "orig_argv", [])))


def is_command(script: str, given: list[str]) -> bool:
    """Whether a process whose ``sys.argv[0]`` is ``script`` and whose ``sys.orig_argv`` is ``given`` is the
    ``stewart-gym`` command: its script by any path (on Windows ``stewart-gym.exe`` or ``stewart-gym-script.py``,
    ``\\`` or ``/`` between folders), or ``python -m stewart_gym``."""
    name = script.replace("\\", "/").rsplit("/", 1)[-1].lower()
    after_m = given[given.index("-m") + 1] if "-m" in given[:-1] else None
    return (name in ("stewart-gym", "stewart-gym.exe", "stewart-gym-script.py")
            or after_m in ("stewart_gym", "stewart_gym.cli"))


#: Whether this process is the ``stewart-gym`` command (:func:`_as_command`): then a stop signal while it loads is
#: noted, and the command stops with its one line as it starts (another program that imports the package, or runs
#: one of its modules, keeps its own handling).
AS_COMMAND = _as_command()
#: The stop signals :func:`note_stops_while_loading` notes instead of their default, with that default (the command
#: line puts it back as its own handlers go in).
NOTED_WHILE_LOADING: list[tuple[int, object]] = []


def _note(signum: int, frame: object) -> None:
    SIGNALS_WHILE_LOADING.append(signum)


def note_stops_while_loading() -> None:
    """Where the process started with SIGINT ignored, note a SIGINT in :data:`SIGNALS_WHILE_LOADING` from now on
    instead of losing it (the command line calls it again as its own modules load, until its handlers are in); in
    the command (:data:`AS_COMMAND`), note Ctrl-C, SIGTERM and SIGHUP too where they are at their default."""
    if SIGINT_IGNORED_AT_START:
        _signal.signal(_signal.SIGINT, _note)
    if AS_COMMAND and _threading.current_thread() is _threading.main_thread():
        for name, default in (("SIGINT", _signal.default_int_handler), ("SIGTERM", _signal.SIG_DFL),
                              ("SIGHUP", _signal.SIG_DFL)):  # fmt: skip
            num = getattr(_signal, name, None)
            if num is not None and _signal.getsignal(num) is default:
                _signal.signal(num, _note)
                NOTED_WHILE_LOADING.append((num, default))


note_stops_while_loading()  # noted, not lost, while the package loads (the command line's first half second)


def _stopped_while_loading(kind: type, value: BaseException, tb: object, _previous=_sys.excepthook) -> None:
    """Ctrl-C while this package loads (the command line's first half second) is one line, not a traceback."""
    if issubclass(kind, KeyboardInterrupt):
        print("error: stopped by Ctrl-C (SIGINT) while loading", file=_sys.stderr)
        return
    _previous(kind, value, tb)


_sys.excepthook = _stopped_while_loading  # until the end of this file: only this import's own interrupt

import importlib  # noqa: E402
import importlib.util  # noqa: E402
from typing import Any  # noqa: E402

__version__ = "0.1.0"

#: The public names and the module each comes from (loaded on first use: PEP 562).
_EXPORTS = {
    "CalibrationError": "stewart_gym.calibration",
    "PulseRangeError": "stewart_gym.calibration",
    "ServoCalibration": "stewart_gym.calibration",
    "ENV_IDS": "stewart_gym.envs",
    "register_envs": "stewart_gym.envs",
    "GeometryError": "stewart_gym.geometry",
    "PlatformGeometry": "stewart_gym.geometry",
    "FKResult": "stewart_gym.kinematics",
    "IKResult": "stewart_gym.kinematics",
    "LegStatus": "stewart_gym.kinematics",
    "actuator_jacobian": "stewart_gym.kinematics",
    "forward_kinematics": "stewart_gym.kinematics",
    "inverse_kinematics": "stewart_gym.kinematics",
    "rotation_matrix": "stewart_gym.kinematics",
    "load_geometry": "stewart_gym.presets",
    "load_preset": "stewart_gym.presets",
    "preset_names": "stewart_gym.presets",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'stewart_gym' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


if importlib.util.find_spec("gymnasium") is not None:  # without the [sim] extra: kinematics, analyses, deploy
    from stewart_gym.envs import register_envs as _register

    _register()

_sys.excepthook = _stopped_while_loading.__defaults__[0]  # type: ignore[index]
if SIGINT_IGNORED_AT_START:  # other programs that import the package keep it ignored
    _signal.signal(_signal.SIGINT, _signal.SIG_IGN)
