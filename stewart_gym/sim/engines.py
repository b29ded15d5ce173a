"""The physics engines behind the backend seam, by name: ``make_backend("pybullet" | "mujoco", …)``."""

from __future__ import annotations

from typing import Any

from stewart_gym.errors import ConfigError
from stewart_gym.sim.backend import PhysicsBackend

__all__ = ["BACKEND_NAMES", "DEFAULT_BACKEND", "backend_class", "default_backend", "make_backend"]

#: Engines :func:`make_backend` builds (MuJoCo needs the ``mujoco`` extra).
BACKEND_NAMES = ("pybullet", "mujoco", "batched")
#: What ``backend="auto"`` (the envs' default) picks: PyBullet, the reference engine, where it imports, else MuJoCo.
DEFAULT_BACKEND = "auto"
_SAID: list[str] = []


def default_backend() -> str:
    """The engine ``"auto"`` means here: ``"pybullet"`` where PyBullet imports, else ``"mujoco"`` (on Python
    3.12 and newer PyBullet has no wheel, and the ``sim`` extra installs MuJoCo instead), said once on stderr.
    :class:`ConfigError` where neither imports."""
    import importlib.util
    import logging

    try:
        import stewart_gym.sim.stewart_sim  # noqa: F401  (PyBullet, imported quietly)

        return "pybullet"
    except ImportError:
        pass
    if importlib.util.find_spec("mujoco") is None:
        raise ConfigError("no physics engine: neither PyBullet nor MuJoCo can be imported; pip install "
                          "'stewart_gym[sim]'")  # fmt: skip
    if not _SAID:
        _SAID.append("mujoco")
        logging.getLogger("stewart_gym").warning(
            "note: PyBullet cannot be imported here (it has no wheel for this Python); the simulator runs on "
            "MuJoCo, whose figures agree with PyBullet's within about 1 mm (docs: The simulator)")  # fmt: skip
    return "mujoco"

#: Hz: PyBullet's physics rate in the envs (the loop gap stays ≤ 0.042 mm under ±10° bang-bang tilts).
PYBULLET_ENV_HZ = 150


def multiple_at_least(rate: int, control_hz: int) -> int:
    """The smallest multiple of ``control_hz`` that is at least ``rate`` (Hz): the physics steps a whole number of
    times per control period (150 Hz physics at 50 Hz control, 200 at 100 Hz)."""
    if control_hz <= 0:
        raise ConfigError(f"control_hz must be a positive number of Hz, got {control_hz!r}")
    return -(-int(rate) // int(control_hz)) * int(control_hz)


def backend_class(name: str) -> type:
    """The simulator class of engine ``name`` (to ask its declared capabilities before building one, such as
    ``renders_camera``)."""
    if name == "pybullet":
        from stewart_gym.sim.stewart_sim import StewartSim

        return StewartSim
    if name == "mujoco":
        from stewart_gym.sim.mujoco_sim import MujocoSim

        return MujocoSim
    if name == "batched":
        from stewart_gym.sim.batched import BatchedPlatform

        return BatchedPlatform
    if name == "auto":
        return backend_class(default_backend())
    raise ConfigError(f"backend must be one of {list(BACKEND_NAMES)}, got {name!r}")


def make_backend(name: str, geometry: Any, *, physics_hz: int | None = None, **kwargs: Any) -> PhysicsBackend:
    """A :class:`PhysicsBackend` of engine ``name`` for ``geometry``; ``kwargs`` go to its constructor
    (``control_hz``, ``ball``, ``ball_spec``, ``servo_spec``, ``render_mode``, …). ``physics_hz`` defaults
    to the engine's env rate (PyBullet 150 Hz, MuJoCo :class:`~stewart_gym.sim.mjcf.MujocoPhysics`'s)."""
    control_hz = int(kwargs.get("control_hz", 50))
    if name == "auto":
        name = default_backend()
    if name == "pybullet":
        from stewart_gym.sim.stewart_sim import StewartSim

        return StewartSim(geometry, physics_hz=physics_hz or multiple_at_least(PYBULLET_ENV_HZ, control_hz), **kwargs)
    if name == "mujoco":
        from stewart_gym.sim.mjcf import MujocoPhysics
        from stewart_gym.sim.mujoco_sim import MujocoSim

        if kwargs.get("render_mode") == "human":
            raise ConfigError("render_mode 'human' is PyBullet's window; with MuJoCo use 'rgb_array' or "
                              "python -m mujoco.viewer on the file from stewart-gym mjcf")  # fmt: skip
        own = (kwargs.get("physics") or MujocoPhysics()).physics_hz
        return MujocoSim(geometry, physics_hz=physics_hz or multiple_at_least(own, control_hz), **kwargs)
    if name == "batched":
        from stewart_gym.sim.batched import BatchedPlatform, BatchedSim

        if kwargs.pop("render_mode", None) is not None:
            raise ConfigError("the batched backend does not render; use backend 'pybullet' or 'mujoco' to watch")
        kwargs.pop("ball", None)  # it always has its ball
        sim = BatchedSim(geometry, n=1, physics_hz=physics_hz or multiple_at_least(PYBULLET_ENV_HZ, control_hz), **kwargs)
        return BatchedPlatform(sim)
    raise ConfigError(f"backend must be one of {list(BACKEND_NAMES)}, got {name!r}")
