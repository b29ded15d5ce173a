"""The physics-backend seam: checks every backend must pass (parametrised over the backends there are).

A second engine joins by adding a factory to ``BACKENDS``; nothing else here changes.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from stewart_gym.sim import BallSpec, PhysicsBackend, ServoSpec, StewartSim
from stewart_gym.sim.engines import make_backend
from stewart_gym.sim.mujoco_sim import MujocoSim

BACKENDS: dict[str, Callable[[], PhysicsBackend]] = {
    "pybullet": lambda: StewartSim(physics_hz=150, ball=True),
    "mujoco": lambda: MujocoSim(ball=True),
    "batched": lambda: make_backend("batched", "servo-hexapod"),
}


@pytest.fixture(params=sorted(BACKENDS), scope="module")
def backend(request: pytest.FixtureRequest) -> PhysicsBackend:
    b = BACKENDS[request.param]()
    yield b
    b.close()


def run(b: PhysicsBackend, seconds: float, pulses: np.ndarray | None = None) -> None:
    for _ in range(int(round(seconds * b.control_hz))):
        if pulses is not None:
            b.command(pulses)
        b.step()


def test_is_a_backend(backend: PhysicsBackend) -> None:
    assert isinstance(backend, PhysicsBackend)
    assert backend.dt == pytest.approx(1.0 / backend.control_hz)
    hx, hy = backend.plate_half_extent
    assert 0.01 < hx < 1.0 and 0.01 < hy < 1.0 and 0.0 <= backend.plate_top < 0.1


def test_reset_is_home_with_the_ball_resting_at_the_centre(backend: PhysicsBackend) -> None:
    backend.reset()
    assert backend.time == 0.0
    run(backend, 0.5)
    assert np.allclose(backend.platform_pose(), 0.0, atol=2e-4)
    x, y, z = backend.ball_position()
    assert math.hypot(x, y) < 1e-3
    assert z == pytest.approx(backend.plate_top + BallSpec().radius, abs=1e-3)
    assert backend.time == pytest.approx(0.5)


def test_a_placed_ball_rolls_down_a_tilted_plate(backend: PhysicsBackend) -> None:
    """Pitch the plate by +3° (through the pulses the IK gives): the ball rolls towards +x."""
    from stewart_gym.kinematics import inverse_kinematics

    backend.reset()
    pose = np.array([0, 0, 0, 0, math.radians(3), 0])
    pulses = backend.calibration.pulse_widths(inverse_kinematics(backend.geometry, pose).servo_angles)
    run(backend, 0.5, pulses)
    backend.place_ball(np.array([0.0, 0.0]))
    x0 = backend.ball_position()[0]
    run(backend, 0.5, pulses)
    assert backend.ball_position()[0] - x0 > 0.01
    assert backend.platform_pose()[4] == pytest.approx(math.radians(3), abs=math.radians(0.2))


def test_place_ball_sets_position_and_velocity(backend: PhysicsBackend) -> None:
    backend.reset()
    backend.place_ball(np.array([0.05, -0.04]), (0.1, 0.0))
    pos, vel = backend.ball_state()
    assert pos[:2] == pytest.approx([0.05, -0.04], abs=1e-6)
    assert vel[:2] == pytest.approx([0.1, 0.0], abs=1e-6)


def test_push_ball_changes_its_velocity_by_impulse_over_mass(backend: PhysicsBackend) -> None:
    backend.reset(ball_spec=BallSpec())
    backend.place_ball(np.zeros(2))
    backend.push_ball((0.0, 0.005))
    _, vel = backend.ball_state()
    assert vel[1] == pytest.approx(0.005 / BallSpec().mass, rel=1e-6) and abs(vel[0]) < 1e-9


def test_reset_takes_the_ball_spec_s_radius_mass_and_inertia(backend: PhysicsBackend) -> None:
    """A ping-pong ball (20 mm, 2.7 g, hollow) instead of the steel one: it rests 20 mm above the plate, a push
    moves it by impulse over its own mass, and on a plate pitched 3° it rolls at (3/5) g sin θ, the hollow ball's
    rate (a solid one's is 5/7 of g sin θ, 19 % more)."""
    ball = BallSpec(radius=0.02, mass=0.0027, hollow=True)
    try:
        _roll_a_ping_pong_ball(backend, ball)
    finally:
        backend.reset(ball_spec=BallSpec())  # (a reset without a ball spec keeps the last ball)


def _roll_a_ping_pong_ball(backend: PhysicsBackend, ball: BallSpec) -> None:
    from stewart_gym.kinematics import inverse_kinematics

    backend.reset(ball_spec=ball)
    run(backend, 0.3)
    assert backend.ball_position()[2] == pytest.approx(backend.plate_top + 0.02, abs=1e-3)
    backend.place_ball(np.zeros(2))
    backend.push_ball((0.0, 0.0001))
    assert backend.ball_state()[1][1] == pytest.approx(0.0001 / 0.0027, rel=1e-6)
    pose = np.array([0, 0, 0, 0, math.radians(3), 0])
    pulses = backend.calibration.pulse_widths(inverse_kinematics(backend.geometry, pose).servo_angles)
    run(backend, 0.5, pulses)
    backend.place_ball(np.zeros(2))
    t = 0.3
    run(backend, t, pulses)
    acceleration = 2 * backend.ball_position()[0] / t**2
    assert acceleration == pytest.approx(0.6 * 9.81 * math.sin(backend.platform_pose()[4]), rel=0.08)


def test_every_backend_name_builds_its_class() -> None:
    """A name in ``BACKEND_NAMES`` is one ``make_backend`` builds and ``backend_class`` names (what
    ``virtual-device --camera-stream`` asks before building one), and the contract runs on it."""
    from stewart_gym.sim.engines import BACKEND_NAMES, backend_class

    assert set(BACKEND_NAMES) == set(BACKENDS)
    for name in BACKEND_NAMES:
        with make_backend(name, "servo-hexapod") as built:
            assert isinstance(built, backend_class(name)), name


def test_a_plate_load_appears_from_the_next_step(backend: PhysicsBackend) -> None:
    """Weak servos sag under an off-centre load put on mid-episode: the plate tips towards it. A backend that
    declares it does not model the servos' torque (``models_plate_load`` False) takes the load and holds the plate
    where it was."""
    backend.reset(servo_spec=ServoSpec(stall_torque=0.15))
    run(backend, 0.3)
    before = backend.platform_pose().copy()
    backend.set_plate_load((1.0, np.array([0.1, 0.0, 0.0])))
    run(backend, 0.3)
    if getattr(backend, "models_plate_load", True):
        assert backend.platform_pose()[4] - before[4] > math.radians(0.05)  # +x side down: positive pitch
    else:
        np.testing.assert_allclose(backend.platform_pose(), before, atol=1e-9)
    backend.set_plate_load(None)
    backend.reset()


def test_commands_outside_the_limits_are_refused(backend: PhysicsBackend) -> None:
    from stewart_gym.calibration import PulseRangeError

    backend.reset()
    with pytest.raises(PulseRangeError):
        backend.command(np.full(6, 5000.0))


def test_an_object_that_is_not_a_backend_is_refused_naming_what_it_lacks() -> None:
    """An engine class half written (here: no ``push_ball``, ``set_plate_load`` nor ``render``): one error naming the
    members it lacks, before anything is built."""
    import gymnasium as gym

    from stewart_gym.errors import ConfigError

    class HalfWritten:
        def __init__(self) -> None:
            self.inner = StewartSim(ball=True)

        def __getattr__(self, name: str):
            if name in ("push_ball", "set_plate_load", "render"):
                raise AttributeError(name)
            return getattr(self.inner, name)

    half = HalfWritten()
    try:
        with pytest.raises(ConfigError, match=r"or a PhysicsBackend, got .* \(it lacks push_ball, render, "
                                              r"set_plate_load\)$"):  # fmt: skip
            gym.make("StewartBallBalance-v0", backend=half)
    finally:
        half.inner.close()


def test_a_backend_class_given_for_an_instance_is_named_so() -> None:
    import gymnasium as gym

    from stewart_gym.errors import ConfigError

    with pytest.raises(ConfigError, match=r"got <class .*StewartSim'> \(a class: pass an instance of it\)$"):
        gym.make("StewartBallBalance-v0", backend=StewartSim)
