"""The package's error classes: the bottom of the layering (imports nothing of the package).

Everything a *user* can get wrong (a malformed file, a bad option, a pose out
of reach, a device that does not answer) raises a subclass of
:class:`StewartGymError`. The command line prints such an error as one line,
``error: …``, and exits non-zero; anything else is a bug and keeps its
traceback. Each class also derives from the built-in exception it refines, so
``except ValueError`` keeps working.
"""

from __future__ import annotations

__all__ = ["ConfigError", "DeviceFailure", "PolicyError", "Stopped", "StewartGymError", "TrainingDiverged",
           "UnreachableError"]


class StewartGymError(Exception):
    """Base class of the errors a user can cause and fix; the message says what was wrong and what to do."""


class ConfigError(StewartGymError, ValueError):
    """An option, a configuration file or an argument is invalid; the message names it."""


class PolicyError(StewartGymError, ValueError):
    """A policy cannot be found or does not fit the environment or the hardware it is used with."""


class UnreachableError(StewartGymError, ValueError):
    """A pose the user asked for is outside the platform's workspace."""


class TrainingDiverged(StewartGymError, RuntimeError):
    """A training run's network gave NaN: its hyperparameters (a learning rate or a loss coefficient too large)
    drove it apart; the message says which to lower and where the run's saved models are."""


class DeviceFailure(StewartGymError, RuntimeError):
    """A serial device failed: unplugged, not answering, or answering wrongly (exit code 2)."""


class Stopped(KeyboardInterrupt):
    """A stop signal (SIGTERM, SIGHUP) raised as Ctrl-C is (SIGINT raises :class:`KeyboardInterrupt` itself), so that
    every ``except KeyboardInterrupt`` that cleans up (the deploy loop's drive home among them) runs for it too.
    The command line exits with 128 + :attr:`signum`."""

    def __init__(self, signum: int, name: str) -> None:
        super().__init__(name)
        self.signum, self.name = int(signum), name
