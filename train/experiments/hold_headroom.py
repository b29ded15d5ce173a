"""How much tighter could a hold be that adapts its gains to each episode? An upper bound for a learned hold.

Run: ``.venv/bin/python -m train.experiments.hold_headroom [--episodes 100] [--gain kp_vel] [--scales 1.0 1.2 1.4]``

The PID + Kalman (``--policy pid-kalman``) holds the ball on the noise and dead-band floor (the docs' Control
page). A learned controller sees the same observations; what it could still add to the hold is adaptation:
gains suited to the episode's panel noise, dead band or servos, which a fixed-gain PID cannot have. This
script bounds that. It evaluates the PID + Kalman with one gain (``--gain``) multiplied by each of
``--scales`` (1.0 is the shipped gains, the reference) on the same ``--episodes`` seeded, randomised balance
episodes (seeds ``--seed`` on), without the settling runs, and prints:

* per gain set: success, RMS error over the last 5 s, final error and the settled servo motion, as
  ``stewart-gym evaluate`` reports them;
* the pooled RMS per gain set within bins of each episode's panel noise and servo dead band (the two
  randomised parameters that most set the hold);
* the best gain set per noise bin, applied by an oracle that knows each episode's noise (picked on these
  same episodes, so optimistic);
* hindsight: each episode's lowest RMS over the gain sets, pooled. No controller can know this in advance,
  and it includes luck, so it bounds what choosing among these gains could buy.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ENV = "StewartBallBalance-v0"
GAINS = ("kp_pos", "kp_vel", "ki_vel")
NOISE_BINS = (0.5, 0.8, 1.1, 1.4, 1.7, 2.0)  # mm: the standard randomisation draws 0.5-2 mm per episode
DEADBAND_BINS = (3.0, 4.0, 5.0, 6.0, 7.0, 8.0)  # µs: 3-8 µs per episode


def evaluate_gains(job: tuple[str, int, int]) -> dict[str, Any]:
    """Evaluate one gain file (in a worker process); the metrics with each episode's figures."""
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    path, episodes, seed = job
    _, policy, env_kwargs = load_for_evaluation(path, ENV, None, None)
    return evaluate(ENV, policy, episodes=episodes, seed=seed, env_kwargs=env_kwargs, settling=False)


def episode_parameters(episodes: int, seed: int, env_kwargs: dict[str, Any]) -> tuple[list[float], list[float]]:
    """Each seeded episode's panel noise (mm) and servo dead band (µs), as the evaluation draws them (the same env
    settings, randomised, the same seeds)."""
    import gymnasium as gym

    import stewart_gym  # noqa: F401 (registers the envs)

    env = gym.make(ENV, **{**env_kwargs, "randomize": True})
    noise, deadband = [], []
    for i in range(episodes):
        env.reset(seed=seed + i)
        noise.append(env.unwrapped.params.sensor.noise_mm)
        deadband.append(env.unwrapped.params.servo.deadband_us)
    env.close()
    return noise, deadband


def pooled(rms: list[float], steps: list[int]) -> float:
    """The RMS over all the episodes' last 5 s together, as ``evaluate`` pools it."""
    from stewart_gym.evaluation import pooled_rms

    return float(pooled_rms(rms, steps))


def in_bin(value: float, lo: float, hi: float, edges: tuple[float, ...]) -> bool:
    """Whether ``value`` falls in the bin [lo, hi) (the last bin includes its upper edge)."""
    return lo <= value < hi or (hi == edges[-1] and value == hi)


def binned(label: str, unit: str, values: list[float], edges: tuple[float, ...], rms: dict[float, list[float]],
           steps: list[int]) -> tuple[list[str], dict[tuple[float, float], float]]:  # fmt: skip
    """Table rows of the pooled RMS per gain set within each bin of ``values``; the best scale per bin."""
    scales = list(rms)
    lines = [f"| {label} ({unit}) | episodes | " + " | ".join(f"×{s:g}" for s in scales) + " |",
             "|---" * (len(scales) + 2) + "|"]  # fmt: skip
    best = {}
    for lo, hi in zip(edges, edges[1:]):
        idx = [i for i, v in enumerate(values) if in_bin(v, lo, hi, edges)]
        if not idx:
            continue
        per = {s: pooled([rms[s][i] for i in idx], [steps[i] for i in idx]) for s in scales}
        best[(lo, hi)] = min(per, key=per.get)
        lines.append(f"| {lo:g}–{hi:g} | {len(idx)} | " + " | ".join(f"{per[s]:.3f}" for s in scales) + " |")
    return lines, best


def run(argv: list[str] | None = None) -> None:
    """Run the experiment with the options of its command line (``argv``; default ``sys.argv[1:]``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episodes", type=int, default=100, help="seeded, randomised balance episodes")
    ap.add_argument("--seed", type=int, default=0, help="the first episode's seed")
    ap.add_argument("--gain", choices=GAINS, default="kp_vel", help="the PID + Kalman gain to scale")
    ap.add_argument("--scales", type=float, nargs="+", default=[1.0, 1.2, 1.4],
                    help="multipliers of that gain; 1.0 (the shipped gains) must be one of them")  # fmt: skip
    ap.add_argument("--workers", type=int, default=2, help="processes at once")
    args = ap.parse_args(argv)
    if args.episodes < 1 or args.workers < 1 or args.seed < 0:
        ap.error("--episodes and --workers must be at least 1, --seed at least 0")
    if not all(math.isfinite(s) and 0 < s <= 10 for s in args.scales) or len(set(args.scales)) != len(args.scales):
        ap.error(f"--scales must be distinct numbers in (0, 10], got {args.scales}")
    if 1.0 not in args.scales:
        ap.error("--scales must include 1.0, the shipped gains, as the reference")

    from stewart_gym.registry import POLICY_DIR

    shipped = json.loads((POLICY_DIR / "pid_kalman_gains.json").read_text())
    with tempfile.TemporaryDirectory() as folder:
        jobs = []
        for s in args.scales:
            path = Path(folder) / f"{args.gain}_x{s:g}.json"
            path.write_text(json.dumps({**shipped, args.gain: shipped[args.gain] * s}))
            jobs.append((str(path), args.episodes, args.seed))
        with ProcessPoolExecutor(min(args.workers, len(jobs))) as pool:
            results = dict(zip(args.scales, pool.map(evaluate_gains, jobs)))
        from stewart_gym.registry import load_for_evaluation

        env_kwargs = load_for_evaluation(jobs[0][0], ENV, None, None)[2]
    noise, deadband = episode_parameters(args.episodes, args.seed, env_kwargs)

    print(f"PID + Kalman, {args.gain} × each scale ({args.gain} = {shipped[args.gain]:g} shipped), {args.episodes} "
          f"randomised balance episodes (seeds {args.seed}…{args.seed + args.episodes - 1})\n")  # fmt: skip
    print("| scale | success | RMS error, last 5 s (mm) | final error (mm) | settled pulse rate (µs/s) | "
          "settled peak-to-peak (µs) |\n|---|---|---|---|---|---|")  # fmt: skip
    for s, m in results.items():
        print(f"| ×{s:g} | {m['success_rate']:.0%} | {m['rms_error_mm']:.3f} | {m['final_error_mm']:.3f} | "
              f"{m['settled_pulse_rate_us_per_s']:.0f} | {m['settled_pulse_p2p_us']:.0f} |")  # fmt: skip
    rms = {s: m["per_episode"]["rms_mm"] for s, m in results.items()}
    steps = results[1.0]["per_episode"]["tail_steps"]
    if any(m["per_episode"]["tail_steps"] != steps for m in results.values()):
        steps = [min(m["per_episode"]["tail_steps"][i] for m in results.values()) for i in range(args.episodes)]
    reference = pooled(rms[1.0], steps)
    for label, unit, values, edges in (("panel noise", "mm", noise, NOISE_BINS),
                                       ("servo dead band", "µs", deadband, DEADBAND_BINS)):  # fmt: skip
        lines, best = binned(label, unit, values, edges, rms, steps)
        print("\n" + "\n".join(lines))
        if label == "panel noise":
            pick = [next((b for (lo, hi), b in best.items() if in_bin(v, lo, hi, edges)), 1.0) for v in values]
            chosen = [rms[p][i] for i, p in enumerate(pick)]
            print("\nnoise oracle (the best scale per noise bin, picked on these episodes): "
                  f"RMS {pooled(chosen, steps):.3f} mm against {reference:.3f} mm with the shipped gains "
                  f"(mean per episode {sum(c - r for c, r in zip(chosen, rms[1.0])) / args.episodes:+.3f} mm)")  # fmt: skip
    hindsight = [min(rms[s][i] for s in rms) for i in range(args.episodes)]
    print(f"\nhindsight (each episode's lowest RMS over the scales): RMS {pooled(hindsight, steps):.3f} mm against "
          f"{reference:.3f} mm (mean per episode {sum(h - r for h, r in zip(hindsight, rms[1.0])) / args.episodes:+.3f} mm)")


if __name__ == "__main__":
    try:
        run()
    except KeyboardInterrupt:
        sys.exit(130)
