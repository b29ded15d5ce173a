"""Environment speed on one core, next to the bare simulator doing the same physical work in the same run.

Run: ``.venv/bin/python bench/bench_env.py [--steps N] [--json]``.

For each registered env id, with randomisation off and on: env steps/s with
random tilt actions (episodes reset when the ball falls). The baseline replays
that run on the env's own ``StewartSim`` without the env: the same pulses
(``command`` + ``step``), and at the same points the same ``reset`` (episode
parameters) and ball placement, so the ball rolls on the plate in both. The
env's cost is reported as a multiple of the replay's: what IK, sensing,
observation, reward and bookkeeping add to the physics.
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


def measure(env_id: str, randomize: bool, steps: int, rounds: int = 20) -> dict:
    """Medians over ``rounds`` rounds of ``steps`` env steps, each followed at once by its replay.

    Interleaving keeps the env and its replay under the same machine load; the
    cost ratio is taken per round.
    """
    env = gym.make(env_id, randomize=randomize).unwrapped  # no wrappers: the env's own cost
    rng = np.random.default_rng(0)
    env_times, sim_times, episodes = [], [], 0
    for r in range(rounds):
        actions = rng.uniform(-1, 1, (steps, env.action_space.shape[0])).astype(np.float32) * 0.3
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
    return {"id": env_id, "randomize": randomize, "physics_hz": physics_hz, "episodes": episodes,
            "steps": steps * rounds, "steps_per_s": round(steps / float(np.median(env_t))),
            "sim_steps_per_s": round(steps / float(np.median(sim_t))),
            "cost_vs_sim": round(float(np.median(env_t / sim_t)), 3),
            "cost_vs_sim_range": [round(float(v), 3) for v in (np.min(env_t / sim_t), np.max(env_t / sim_t))]}


def env_loop_gap(steps: int = 2000) -> float:
    """Worst loop-closure gap (m) over random full-range tilt actions (±1: ±10° bang-bang) in the balance env."""
    env = gym.make("StewartBallBalance-v0").unwrapped
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=1000, help="env steps per round")
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    res = {"envs": [measure(env_id, randomize, args.steps, args.rounds)
                    for env_id in stewart_gym.ENV_IDS for randomize in (False, True)],
           "loop_gap_full_tilt_mm": round(env_loop_gap() * 1e3, 4)}  # fmt: skip
    if args.json:
        print(json.dumps(res))
        return
    print(f"env steps/s (one process, random tilt actions, resets included; medians of {args.rounds} rounds of "
          f"{args.steps} steps), next to the bare StewartSim replaying each round")  # fmt: skip
    for r in res["envs"]:
        lo, hi = r["cost_vs_sim_range"]
        print(f"  {r['id']:24s} randomize={r['randomize']!s:5s} {r['steps_per_s']:>6,} steps/s   "
              f"sim replay {r['sim_steps_per_s']:>6,}/s   env cost {r['cost_vs_sim']:.2f}× the sim's "
              f"({lo:.2f}–{hi:.2f})   ({r['physics_hz']} Hz physics, {r['episodes']} episodes)")  # fmt: skip
    print("targets: ≥ 3,000 env steps/s and ≤ 1.3× the sim's cost")
    print(f"worst loop gap in the env under random ±10° bang-bang tilt actions: {res['loop_gap_full_tilt_mm']:.4f} mm")


if __name__ == "__main__":
    main()
