"""Tune the cascaded PID baseline by grid search, on the same randomised task the RL policy faces.

Each gain set runs ``--episodes`` seeded episodes of StewartBallBalance-v0 with
randomisation (seeds 10000…, disjoint from the evaluation seeds 0…99). The best
set maximises the success rate; among the sets with that rate whose RMS error is
within 10 % of the lowest, it is the one that moves the servos least once the
ball is held (settled pulse rate). ``--estimator`` picks the observer the PID
runs behind: ``kalman`` (the default) writes ``policies/pid_kalman_gains.json``
(``--policy pid-kalman``), ``lowpass`` ``policies/pid_gains.json`` (``--policy
pid``); ``--out`` writes elsewhere. ``--kp-pos``, ``--kp-vel`` and ``--ki-vel``
give the grid; ``--integral-zone-mm`` (default 20) the conditional integration zone
(the error is integrated only this close to the target). ``--twin FILE`` tunes for a platform's twin (each
episode drawn around it, as ``train --twin`` draws them); ``--out`` is then required. Prints the table.

Run: ``.venv/bin/python train/tools/tune_pid.py [--episodes 30] [--estimator kalman]``
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import asdict
from pathlib import Path

from stewart_gym.control import CascadedPID, PIDGains
from stewart_gym.evaluation import evaluate
from stewart_gym.registry import POLICY_DIR


def floats(text: str) -> list[float]:
    """A comma-separated list of numbers: ``1,1.5,2``."""
    return [float(v) for v in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--out", help="gains file to write (default: the shipped one for --estimator)")
    parser.add_argument("--estimator", choices=["lowpass", "kalman"], default="kalman")
    parser.add_argument("--kp-pos", type=floats, default=[1.0, 1.5, 2.0, 3.0])
    parser.add_argument("--kp-vel", type=floats, default=[2.0, 3.0, 4.0, 5.0])
    parser.add_argument("--ki-vel", type=floats, default=[2.0, 3.0, 4.0])
    parser.add_argument("--integral-zone-mm", type=float, default=20.0,
                        help="integrate the error only this close to the target (0: always; default 20)")
    parser.add_argument("--twin", help="tune for this twin (TOML, as sysid writes it); needs --out")
    args = parser.parse_args()
    env_kwargs: dict = {"estimator": args.estimator}
    if args.twin:
        from stewart_gym.sim.twin import load_twin

        if not args.out:
            parser.error("--twin needs --out (the shipped gains are for the nominal platform)")
        env_kwargs["twin"] = load_twin(args.twin).to_mapping()
    args.out = args.out or str(POLICY_DIR / ("pid_kalman_gains.json" if args.estimator == "kalman" else "pid_gains.json"))
    grid = itertools.product(args.kp_pos, args.kp_vel, args.ki_vel)
    rows = []
    for kp_pos, kp_vel, ki_vel in grid:
        gains = PIDGains(kp_pos=kp_pos, kp_vel=kp_vel, ki_vel=ki_vel, integral_zone=args.integral_zone_mm * 1e-3)
        m = evaluate("StewartBallBalance-v0", CascadedPID(gains), episodes=args.episodes, seed=10_000, settling=False,
                     env_kwargs=env_kwargs)  # fmt: skip
        rows.append((m["success_rate"], -m["rms_error_mm"], gains, m))
        print(f"kp_pos={kp_pos:4.1f} kp_vel={kp_vel:4.1f} ki_vel={ki_vel:3.1f}  success {m['success_rate']:.0%}  "
              f"RMS {m['rms_error_mm']:.2f} mm  final {m['final_error_mm']:.2f} mm  settled "
              f"{m['settled_pulse_rate_us_per_s']:.0f} us/s, p2p {m['settled_pulse_p2p_us']:.0f} us",
              flush=True)  # fmt: skip
    top = max(r[0] for r in rows)
    lowest = min(-r[1] for r in rows if r[0] == top)
    near = [r for r in rows if r[0] == top and -r[1] <= 1.1 * lowest]
    best = min(near, key=lambda r: (r[3]["settled_pulse_rate_us_per_s"], -r[1]))
    Path(args.out).write_text(json.dumps({**asdict(best[2]), "estimator": args.estimator}, indent=2) + "\n")
    m = best[3]
    print(f"best: {asdict(best[2])} → {args.out}: success {m['success_rate']:.0%}, RMS {m['rms_error_mm']:.2f} mm")


if __name__ == "__main__":
    main()
