"""Kinematics throughput on one core: batched servo IK, a per-pose loop, single-pose latency, an
out-of-reach action's ray search, FK.

Run: ``.venv/bin/python bench/bench_kinematics.py`` (or ``make bench``). BLAS is
limited to one thread so the figures are for one core. Prints a table and, with
``--json``, one JSON object.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402

from stewart_gym.actions import ActionMapper  # noqa: E402
from stewart_gym.calibration import ServoCalibration, servo_pulses_one  # noqa: E402
from stewart_gym.cli.common import int_at_least  # noqa: E402
from stewart_gym.geometry import PlatformGeometry  # noqa: E402
from stewart_gym.kinematics import forward_kinematics, inverse_kinematics  # noqa: E402
from stewart_gym.presets import load_preset  # noqa: E402


def median_latency_us(call: Callable[[], object], repeats: int = 7, number: int = 5000) -> float:
    """Median over ``repeats`` of the mean time of ``number`` calls, µs."""
    lat = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            call()
        lat.append((time.perf_counter() - t0) / number)
    return float(np.median(lat)) * 1e6


def naive_servo_ik(geo: PlatformGeometry, pose: np.ndarray) -> np.ndarray:
    """A straightforward per-pose implementation, as a first script would write it."""
    x, y, z, roll, pitch, yaw = pose
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0], [-math.sin(pitch), 0, math.cos(pitch)]])
    rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)], [0, math.sin(roll), math.cos(roll)]])
    rot = rz @ ry @ rx
    t = np.array([x, y, z + geo.home_height])
    a, s = geo.horn_length, geo.rod_length
    out = np.empty(6)
    for i in range(6):
        q = t + rot @ geo.platform_anchors[i]
        b = geo.base_anchors[i]
        leg = q - b
        big_l = leg @ leg - (s * s - a * a)
        big_m = 2 * a * (q[2] - b[2])
        beta = geo.servo_beta[i]
        big_n = 2 * a * (math.cos(beta) * (q[0] - b[0]) + math.sin(beta) * (q[1] - b[1]))
        ratio = big_l / math.sqrt(big_m * big_m + big_n * big_n)
        out[i] = math.asin(ratio) - math.atan2(big_n, big_m) if abs(ratio) <= 1 else math.nan
    return out


def best_of(fn, repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--poses", type=int_at_least(1), default=1_000_000)
    parser.add_argument("--loop-poses", type=int_at_least(1), default=20_000, help="poses timed in the per-pose loops")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    geo = load_preset("servo-hexapod")
    rng = np.random.default_rng(0)
    scale = np.array([0.02, 0.02, 0.01, math.radians(8), math.radians(8), math.radians(15)])
    poses = rng.uniform(-1, 1, (args.poses, 6)) * scale
    inverse_kinematics(geo, poses[:1000])  # warm-up

    t_batch = best_of(lambda: inverse_kinematics(geo, poses), 5)
    batch_rate = args.poses / t_batch
    reach = float(inverse_kinematics(geo, poses).reachable.mean())

    sub = poses[: args.loop_poses]
    t_naive = best_of(lambda: [naive_servo_ik(geo, p) for p in sub], 2)
    naive_rate = len(sub) / t_naive
    t_api = best_of(lambda: [inverse_kinematics(geo, p) for p in sub], 2)
    api_rate = len(sub) / t_api

    one = poses[0]
    latency_us = median_latency_us(lambda: inverse_kinematics(geo, one))
    cal = ServoCalibration.default(geo)
    reachable_one = poses[:100][inverse_kinematics(geo, poses[:100]).reachable][0].tolist()
    control_us = median_latency_us(lambda: servo_pulses_one(geo, cal, reachable_one))

    corner = np.array([1.0, 1.0])  # a diagonal tilt at the action's limit: out of reach, so the ray search
    fresh = [ActionMapper(geo, cal, "tilt") for _ in range(200)]
    first = []
    for mapper in fresh:
        t0 = time.perf_counter()
        mapper(corner)
        first.append(time.perf_counter() - t0)
    corner_first_us = float(np.median(first)) * 1e6
    corner_again_us = median_latency_us(lambda: fresh[0](corner))

    ik = inverse_kinematics(geo, poses[:100_000])
    angles = ik.servo_angles[ik.reachable]
    t_fk = best_of(lambda: forward_kinematics(geo, servo_angles=angles), 3)
    fk = forward_kinematics(geo, servo_angles=angles)
    fk_err = float(np.abs(fk.pose - poses[:100_000][ik.reachable]).max())

    res = {
        "poses": args.poses,
        "reachable_fraction": round(reach, 4),
        "batched_ik_poses_per_s": round(batch_rate),
        "naive_loop_poses_per_s": round(naive_rate),
        "api_loop_poses_per_s": round(api_rate),
        "speedup_vs_naive_loop": round(batch_rate / naive_rate, 1),
        "speedup_vs_api_loop": round(batch_rate / api_rate, 1),
        "single_pose_latency_us": round(latency_us, 2),
        "control_path_latency_us": round(control_us, 2),
        "unreachable_corner_first_us": round(corner_first_us, 1),
        "unreachable_corner_again_us": round(corner_again_us, 1),
        "fk_solves_per_s": round(len(angles) / t_fk),
        "fk_mean_iterations": round(float(fk.iterations.mean()), 2),
        "fk_max_error": fk_err,
    }
    if args.json:
        print(json.dumps(res))
        return
    print(f"servo-hexapod, one core, {args.poses:,} random poses ({reach:.1%} reachable)")
    print(f"  batched servo IK          {batch_rate:>14,.0f} poses/s   (target ≥ 2,000,000)")
    print(f"  naive per-pose loop       {naive_rate:>14,.0f} poses/s   → batched is {batch_rate / naive_rate:.0f}×")
    print(f"  loop over single-pose API {api_rate:>14,.0f} poses/s   → batched is {batch_rate / api_rate:.0f}×")
    print(f"  single-pose latency       {latency_us:>14.1f} µs        (target ≤ 30)")
    print(f"  one pose → pulses, scalar {control_us:>14.1f} µs        (servo_pulses_one)")
    print(f"  out-of-reach tilt → pulses{corner_first_us:>14.1f} µs        (ActionMapper: the ray search; "
          f"{corner_again_us:.1f} µs when the same pose comes again)")
    print(f"  batched FK (Newton)       {len(angles) / t_fk:>14,.0f} solves/s  "
          f"({fk.iterations.mean():.1f} iterations, max error {fk_err:.1e})")  # fmt: skip


if __name__ == "__main__":
    main()
