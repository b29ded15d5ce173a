"""The batched simulator's two kernels (:mod:`stewart_gym.sim.batched_kernel`, compiled with numba, and the NumPy
path): the same motion to rounding, platform by platform, whatever each platform's servos, ball, commands, resets
and pushes; the choice of kernel checked at the edge; and :func:`~stewart_gym.compiled.exp_each` as Python's
``math.exp`` to the last bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stewart_gym.compiled import exp_each
from stewart_gym.errors import ConfigError
from stewart_gym.sim import BallSpec, ServoSpec, batched_kernel
from stewart_gym.sim.batched import BatchedSim

N = 48


def run_both(physics_hz: int, control_hz: int, seed: int) -> tuple[BatchedSim, BatchedSim, list[np.ndarray]]:
    """Both kernels through 3 s of the same random pulse sequences, per-platform servos (lag, dead band, trim,
    speed, resolution) and balls, with a platform reset and a push mid-run; each step's (ball xy, pose, servo
    angles) differences."""
    rng = np.random.default_rng(seed)
    servos = [ServoSpec(lag_s=float(rng.uniform(0.0, 0.03)), deadband_us=float(rng.uniform(0.0, 4.0)),
                        trim_error_us=tuple(rng.uniform(-8.0, 8.0, 6)), max_speed=float(rng.uniform(4.0, 9.0)),
                        resolution_us=float(rng.choice([0.0, 1.0])))
              for _ in range(N)]  # fmt: skip
    balls = [BallSpec(radius=float(rng.uniform(0.01, 0.02)), mass=float(rng.uniform(0.005, 0.05)),
                      hollow=bool(rng.integers(2))) for _ in range(N)]
    sims = [BatchedSim("servo-hexapod", n=N, physics_hz=physics_hz, control_hz=control_hz, kernel=kernel)
            for kernel in ("numba", "numpy")]  # fmt: skip
    start = rng.uniform(-0.03, 0.03, (N, 2))
    for sim in sims:
        sim.reset(servo_specs=servos, ball_specs=balls)
        sim.place_ball(start, velocity_xy=-start)
    steps = 3 * control_hz
    amplitude, phase = rng.uniform(20.0, 120.0, (N, 1)), rng.uniform(0.0, 6.3, (N, 6))
    differences = []
    for k in range(steps):
        pulses = sims[0].calibration.neutral_us + amplitude * np.sin(2 * np.pi * 0.8 * k / control_hz + phase)
        for sim in sims:
            if k == steps // 3:
                sim.reset_platform(7, servos[8], balls[9])
                sim.push(11, (0.002, -0.001))
            if k % 5 == 0:
                sim.command(pulses)
            else:
                sim.command_one(k % N, pulses[k % N])
            sim.step()
        a, b = sims
        np.testing.assert_array_equal(a.held_pulses(), b.held_pulses())  # the lags and dead bands alike, exactly
        differences.append(np.array([np.abs(a.ball_xy - b.ball_xy).max(),
                                     np.abs(a.platform_pose() - b.platform_pose()).max(),
                                     np.abs(a.alpha - b.alpha).max()]))  # fmt: skip
    return sims[0], sims[1], differences


@pytest.mark.parametrize(("physics_hz", "control_hz", "seed"), [(200, 50, 0), (240, 60, 1), (100, 100, 2)])
def test_the_compiled_and_numpy_kernels_move_alike(physics_hz: int, control_hz: int, seed: int) -> None:
    """Ball within 1e-10 m, pose within 1e-10 m or rad, and servo angles within 1e-12 rad of each other at every
    step for 3 s, where the balls roll tens of millimetres."""
    compiled, numpy_path, differences = run_both(physics_hz, control_hz, seed)
    assert compiled.kernel == "numba" and numpy_path.kernel == "numpy"
    worst = np.max(differences, axis=0)
    assert worst[0] < 1e-10 and worst[1] < 1e-10 and worst[2] < 1e-12, worst
    travelled = np.abs(compiled.ball_xy).max()
    assert 0.005 < travelled < 10.0, travelled  # the balls moved (and neither kernel blew up)
    np.testing.assert_array_equal(compiled.held_pulses(), numpy_path.held_pulses())


def test_a_platform_computes_the_same_whatever_its_neighbours() -> None:
    """The compiled kernel gives platform i the same numbers to the last bit alone (N = 1) or among others, in a
    full group of lanes or in the last, partial one (19 = 8 + 8 + 3), beside a neighbour whose servo angles went
    NaN and one whose ball went to infinity: the batched vector env's copies equal one env's to the last bit."""
    assert batched_kernel.LANES == 8
    rng = np.random.default_rng(4)
    many, alone = BatchedSim(n=19), {i: BatchedSim(n=1) for i in (5, 8, 17)}
    start = rng.uniform(-0.02, 0.02, (19, 2))
    many.place_ball(start)
    for i, one in alone.items():
        one.place_ball(start[i : i + 1])
    for step in range(60):
        if step == 20:  # neighbours in the same groups of lanes break down
            many.alpha[4] = np.nan
            many.ball_xy[16] = np.inf
        pulses = many.calibration.neutral_us + rng.uniform(-90.0, 90.0, (19, 6))
        many.command(pulses)
        many.step()
        for i, one in alone.items():
            one.command(pulses[i : i + 1])
            one.step()
    assert np.isnan(many.platform_pose()[4]).any() and not np.isfinite(many.ball_xy[16]).all()
    for i, one in alone.items():
        np.testing.assert_array_equal(many.ball_xy[i], one.ball_xy[0])
        np.testing.assert_array_equal(many.ball_velocity[i], one.ball_velocity[0])
        np.testing.assert_array_equal(many.platform_pose()[i], one.platform_pose()[0])
        np.testing.assert_array_equal(many.alpha[i], one.alpha[0])


def test_the_kernel_is_checked_and_auto_falls_back_to_numpy(monkeypatch) -> None:
    with pytest.raises(ConfigError, match="kernel: one of auto, numba, numpy, got 'fast'"):
        BatchedSim(n=2, kernel="fast")
    assert BatchedSim(n=2).kernel == "numba"  # numba is in the sim extra
    monkeypatch.setattr(batched_kernel, "AVAILABLE", False)  # as where numba is not installed
    assert BatchedSim(n=2).kernel == "numpy"
    with pytest.raises(ConfigError, match="kernel 'numba' needs numba"):
        BatchedSim(n=2, kernel="numba")


def test_exp_each_is_math_exp_to_the_last_bit() -> None:
    x = -np.random.default_rng(5).uniform(0.0, 40.0, 100_000)
    x[:8] = [0.0, -0.0, -1e-300, -745.2, -746.0, -np.inf, np.nan, 3.0]
    got = exp_each(x)
    expected = np.array([math.exp(v) for v in x.tolist()])
    np.testing.assert_array_equal(got, expected)  # NaN where NaN, every other number bit for bit
    assert np.array_equal(got.view(np.int64)[~np.isnan(x)], expected.view(np.int64)[~np.isnan(x)])


def test_without_numba_the_batched_envs_run_on_the_numpy_kernel() -> None:
    """Where numba is not installed (its import blocked here, in a fresh process): the batched simulator takes
    the NumPy kernel, the vector env steps, and its rewards take ``math.exp``'s numbers from Python."""
    import subprocess
    import sys

    script = """
import sys
sys.modules["numba"] = None  # as if numba were not installed: importing it raises ImportError
import gymnasium as gym, numpy as np, stewart_gym
from stewart_gym import compiled
from stewart_gym.sim.batched import BatchedSim
assert not compiled.AVAILABLE and compiled.compiled(len) is None
assert BatchedSim(n=2).kernel == "numpy"
env = gym.make_vec("StewartBallBalance-v0", num_envs=4, vectorization_mode="vector_entry_point")
env.reset(seed=0)
for _ in range(5):
    obs, reward, *_ = env.step(np.zeros((4, 2), np.float32))
assert env.unwrapped.sim.kernel == "numpy" and np.isfinite(reward).all() and np.isfinite(obs).all()
print("ok")
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr[-2000:]


def test_with_nowhere_to_cache_the_loops_compile_in_each_process() -> None:
    """Where numba finds no writable place for its cache (a read-only install with no writable home: here numba's
    cache locators are emptied before the package loads), importing the package still works and the compiled
    loops run, compiled in the process."""
    import subprocess
    import sys

    script = """
import numba.core.caching as caching
caching.CacheImpl._locator_classes = []  # numba finds no cache location, as in a read-only install
import numpy as np
from stewart_gym.compiled import exp_each
from stewart_gym.sim.batched import BatchedSim
sim = BatchedSim(n=3)
sim.command(np.broadcast_to(sim.calibration.neutral_us + 30.0, (3, 6)))
sim.step()
assert sim.kernel == "numba" and np.isfinite(sim.ball_xy).all() and exp_each(np.zeros(2)).tolist() == [1.0, 1.0]
print("ok")
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr[-2000:]


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_commands_to_some_platforms_only_do_not_pile_up(monkeypatch, kernel: str) -> None:
    """Commands sent to one platform at a time (``command_one``), with long and short lags and resets: the
    simulator keeps only the commands a platform can still act on, and moves exactly as one that keeps them all."""
    from stewart_gym.sim import batched

    rng = np.random.default_rng(6)
    servos = [ServoSpec(lag_s=float(lag)) for lag in rng.choice([0.0, 0.02, 0.2], 6)]
    sims, limit = [], batched.PRUNE_FROM
    for prune_from in (limit, 10**9):  # the second keeps every command: the reference
        monkeypatch.setattr(batched, "PRUNE_FROM", prune_from)
        sim = BatchedSim("servo-hexapod", n=6, kernel=kernel)
        sim.reset(servo_specs=servos)
        sims.append(sim)
        kept = []
        for k in range(240):
            if k == 100:
                sim.reset_platform(2, servos[3])
            i = int(rng.integers(4)) if k < 200 else 0  # platforms 4 and 5 get nothing; at the end only 0
            sim.command_one(i, sim.calibration.neutral_us + rng.uniform(-80.0, 80.0, 6))
            sim.step()
            kept.append(sim.commands_in_flight)
        rng = np.random.default_rng(6)
        rng.choice([0.0, 0.02, 0.2], 6)  # the same draws again for the reference
        sims[-1].kept = kept
    pruned, everything = sims
    np.testing.assert_array_equal(pruned.held_pulses(), everything.held_pulses())
    np.testing.assert_array_equal(pruned.alpha, everything.alpha)
    assert max(pruned.kept) <= limit + 1 < max(everything.kept)
