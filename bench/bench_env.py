"""Environment speed on one core, for each backend (PyBullet, MuJoCo, the batched simulator's one env), next to the
bare simulator doing the same physical work in the same run.

Run: ``.venv/bin/python bench/bench_env.py [--steps N] [--rounds R] [--backends pybullet mujoco] [--json]``.

For each engine and each registered env id, with randomisation off and on: env
steps/s with random tilt actions (±0.3; episodes reset when the ball falls).
Then, for the balance env with randomisation, every action mode with random
actions over the whole action space (in "pose" mode most of them are out of
reach and take the ray search). The baseline replays each run on the env's own
backend without the env: the same pulses (``command`` + ``step``), and at the
same points the same ``reset`` (episode parameters) and ball placement, so the
ball rolls on the plate in both. The env's cost is reported as a multiple of
the replay's: what IK, sensing, observation, reward and bookkeeping add to the
physics. Last, each engine's worst loop gap in the env under random ±10°
bang-bang tilts: the speed is only worth quoting at that fidelity (the batched
simulator has no rods to gap: it closes the chains by Newton's method), MuJoCo's
speed over PyBullet's where both run, and the Kalman observer's filter alone, per
control step.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import stewart_gym  # noqa: E402
from stewart_gym.envs.ball_env import StewartBallEnv  # noqa: E402


@dataclass
class Episode:
    """What the replay needs of one episode: its reset and the pulses of its steps."""

    params: object
    ball_xy: np.ndarray
    ball_velocity: np.ndarray
    pulses: list[np.ndarray] = field(default_factory=list)


def _reset(env: StewartBallEnv, seed: int | None, rng: np.random.Generator, log: list[Episode]) -> None:
    xy, vel = rng.uniform(-0.1, 0.1, 2), rng.uniform(-0.1, 0.1, 2)
    env.reset(seed=seed, options={"ball_position": xy, "ball_velocity": vel})
    log.append(Episode(env.params, xy, vel))


def env_run(env: StewartBallEnv, actions: np.ndarray, seed: int) -> tuple[float, list[Episode]]:
    """Seconds for ``len(actions)`` env steps (resets included, the first excepted) and the log for the replay."""
    rng, log = np.random.default_rng(seed), []
    _reset(env, seed, rng, log)
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, _, info = env.step(a)
        log[-1].pulses.append(info["pulse_widths_us"])
        if terminated:
            _reset(env, None, rng, log)
    elapsed = time.perf_counter() - t0
    return elapsed, log


def sim_replay(env: StewartBallEnv, log: list[Episode]) -> float:
    """Seconds for the bare simulator to redo ``log``: same resets, ball placements and pulses."""
    sim = env.sim
    t0 = time.perf_counter()
    for i, ep in enumerate(log):
        p = ep.params
        if i:  # the first reset happened before the env's clock started
            sim.reset(servo_spec=p.servo, ball_spec=p.ball, plate_friction=p.plate_friction, plate_load=p.plate_load)
            sim.place_ball(ep.ball_xy, ep.ball_velocity)
        for w in ep.pulses:
            sim.command(w)
            sim.step()
    return time.perf_counter() - t0


def measure(env_id: str, randomize: bool, steps: int, rounds: int = 20, backend: str = "pybullet",
            mode: str = "tilt", scale: float = 0.3, estimator: str = "lowpass") -> dict:  # fmt: skip
    """Medians over ``rounds`` rounds of ``steps`` env steps, each followed at once by its replay.

    Actions are uniform in ±``scale``. Interleaving keeps the env and its
    replay under the same machine load; the cost ratio is taken per round.
    """
    env = gym.make(env_id, randomize=randomize, backend=backend, action_mode=mode,
                   estimator=estimator).unwrapped  # the env's own cost
    rng = np.random.default_rng(0)
    env_times, sim_times, episodes = [], [], 0
    for r in range(rounds):
        actions = rng.uniform(-1, 1, (steps, env.action_space.shape[0])).astype(np.float32) * scale
        elapsed, log = env_run(env, actions, seed=r)
        p = log[0].params
        env.sim.reset(servo_spec=p.servo, ball_spec=p.ball, plate_friction=p.plate_friction, plate_load=p.plate_load)
        env.sim.place_ball(log[0].ball_xy, log[0].ball_velocity)
        env_times.append(elapsed)
        sim_times.append(sim_replay(env, log))
        episodes += len(log)
    physics_hz = env.sim.physics_hz
    env.close()
    env_t, sim_t = np.array(env_times), np.array(sim_times)
    return {"backend": backend, "id": env_id, "mode": mode, "actions": f"±{scale:g}", "randomize": randomize,
            "estimator": estimator,
            "physics_hz": physics_hz, "episodes": episodes,
            "steps": steps * rounds, "steps_per_s": round(steps / float(np.median(env_t))),
            "sim_steps_per_s": round(steps / float(np.median(sim_t))),
            "cost_vs_sim": round(float(np.median(env_t / sim_t)), 3),
            "cost_vs_sim_range": [round(float(v), 3) for v in (np.min(env_t / sim_t), np.max(env_t / sim_t))]}


def env_loop_gap(backend: str = "pybullet", steps: int = 2000) -> float:
    """Worst loop-closure gap (m) over random full-range tilt actions (±1: ±10° bang-bang) in the balance env."""
    env = gym.make("StewartBallBalance-v0", backend=backend).unwrapped
    rng = np.random.default_rng(1)
    env.reset(seed=1)
    worst = 0.0
    for a in rng.choice([-1.0, 1.0], (steps, 2)).astype(np.float32):
        _, _, terminated, _, _ = env.step(a)
        worst = max(worst, env.sim.constraint_error())
        if terminated:
            env.reset()
    env.close()
    return worst


def kalman_step_us(steps: int = 5000, rounds: int = 7) -> float:
    """µs per control step of the Kalman observer's filter alone (a command, a reading 11 ms old and the
    prediction for now, at 50 Hz): the median of ``rounds`` rounds of ``steps`` steps."""
    from stewart_gym.sensing import BallKalmanFilter

    times = []
    for _ in range(rounds):
        kf = BallKalmanFilter()
        kf.reset(0.0, (0.01, 0.02))
        t0 = time.perf_counter()
        for k in range(1, steps + 1):
            now = 0.02 * k
            kf.command(now, (0.01 * np.sin(k * 0.01), 0.02 * np.cos(k * 0.013)))
            kf.update(now - 0.011, (0.01 + 1e-3 * np.sin(k * 0.7), 0.02 + 1e-3 * np.cos(k * 1.1)))
            kf.estimate(now)
        times.append((time.perf_counter() - t0) / steps)
    return float(np.median(times)) * 1e6


def main() -> None:
    from stewart_gym.sim.engines import BACKEND_NAMES

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=1000, help="env steps per round")
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--backends", nargs="+", choices=BACKEND_NAMES, default=list(BACKEND_NAMES))
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows, gaps = [], {}
    for backend in args.backends:
        rows += [measure(env_id, randomize, args.steps, args.rounds, backend)
                 for env_id in stewart_gym.ENV_IDS for randomize in (False, True)]  # fmt: skip
        rows += [measure("StewartBallBalance-v0", True, args.steps, args.rounds, backend, mode, 1.0)
                 for mode in ("tilt", "pose", "pulse")]  # fmt: skip
        rows.append(measure("StewartBallBalance-v0", True, args.steps, args.rounds, backend, "tilt", 1.0, "kalman"))
        if backend != "batched":  # (its chains are closed by Newton's method, with no rods to gap)
            gaps[backend] = round(env_loop_gap(backend) * 1e3, 4)
    res = {"envs": rows, "loop_gap_full_tilt_mm": gaps, "kalman_filter_step_us": round(kalman_step_us(), 1)}
    speed = {(r["backend"], r["id"], r["mode"], r["actions"], r["randomize"]): r["steps_per_s"] for r in rows
             if r["estimator"] == "lowpass"}  # fmt: skip
    if {"pybullet", "mujoco"} <= set(args.backends):
        res["mujoco_vs_pybullet"] = {f"{k[1]} {k[2]} {k[3]} randomize={k[4]}": round(v / speed[("pybullet", *k[1:])], 2)
                                     for k, v in speed.items() if k[0] == "mujoco"}  # fmt: skip
    if args.json:
        print(json.dumps(res))
        return
    print(f"env steps/s (one process, resets included; medians of {args.rounds} rounds of {args.steps} steps), next "
          "to the bare backend replaying each round")  # fmt: skip
    for r in rows:
        lo, hi = r["cost_vs_sim_range"]
        print(f"  {r['backend']:8s} {r['id']:24s} {r['mode']:5s} {r['actions']:4s} randomize={r['randomize']!s:5s} "
              f"{r['steps_per_s']:>6,} steps/s   sim replay {r['sim_steps_per_s']:>6,}/s   env cost "
              f"{r['cost_vs_sim']:.2f}× ({lo:.2f}–{hi:.2f})   ({r['physics_hz']} Hz physics, {r['episodes']} episodes)"
              + ("   Kalman observer" if r["estimator"] == "kalman" else ""))
    print(f"the Kalman observer's filter alone: {res['kalman_filter_step_us']:.1f} µs a control step (a command, a "
          "reading and the prediction for now)")
    for name, ratio in res.get("mujoco_vs_pybullet", {}).items():
        print(f"  MuJoCo / PyBullet, {name}: {ratio:.2f}×")
    for backend, gap in gaps.items():
        print(f"worst loop gap in the env under random ±10° bang-bang tilt actions, {backend}: {gap:.4f} mm")


if __name__ == "__main__":
    main()
