"""Deploy-loop compute latency per tick: observation → ONNX policy → IK → safety → protocol bytes.

Run: ``.venv/bin/python bench/bench_deploy.py [--bundle DIR] [--json]``. Uses a bundle (default: the shipped
balance PPO's; ``stewart_gym/policies/balance_residual/bundle`` is the shipped residual, 6 networks in one ONNX
graph beside the LQR → PID) on onnxruntime with one thread, behind its observer (the Kalman filter), and the
Maestro framing; no serial I/O is timed. It also times the policy's call alone (observation → action) and
the observer's alone (reading → observation, on the same clock). The
ticks and the readings' ages jitter as a real clock's do (the tick up to 1 ms late, readings 5–15 ms old):
on an exact 20 ms grid the filter's per-interval matrices would always come from its cache.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from stewart_gym.actions import ActionMapper  # noqa: E402
from stewart_gym.calibration import ServoCalibration  # noqa: E402
from stewart_gym.cli.common import int_at_least  # noqa: E402
from stewart_gym.errors import PolicyError  # noqa: E402
from stewart_gym.hardware.deploy import DeployLoop  # noqa: E402
from stewart_gym.hardware.export import BundlePolicy  # noqa: E402
from stewart_gym.hardware.serial_controllers import MaestroController  # noqa: E402
from stewart_gym.registry import POLICY_DIR  # noqa: E402


class _NullSerial:
    """Stands in for the port: frames are built, not written."""

    port = "null"
    is_open = True

    def write(self, data: bytes) -> int:
        return len(data)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.is_open = False


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--ticks", type=int_at_least(2), default=20_000)
    parser.add_argument("--bundle", default=str(POLICY_DIR / "balance" / "bundle"), help="an exported bundle folder")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    cal = ServoCalibration.default("servo-hexapod")
    try:
        policy = BundlePolicy(args.bundle)
    except PolicyError as exc:
        sys.exit(f"error: {exc}")
    controller = MaestroController(_NullSerial())  # type: ignore[arg-type]
    loop = DeployLoop(policy, ActionMapper("servo-hexapod", cal, policy.action_mode), controller, sensor=None)  # type: ignore[arg-type]
    rng = np.random.default_rng(0)
    readings = rng.normal(0, 0.03, (args.ticks, 2))
    ticks = np.arange(args.ticks) * 0.02 + rng.uniform(0.0, 1e-3, args.ticks)
    ages = rng.uniform(0.005, 0.015, args.ticks)
    times = np.empty(args.ticks)
    for k in range(args.ticks):
        t0 = time.perf_counter()
        reading = ((float(readings[k, 0]), float(readings[k, 1])), float(ages[k]))
        _, _, pulses, _ = loop.compute(reading, float(ticks[k]))
        controller.send(pulses)
        times[k] = time.perf_counter() - t0
    times *= 1e3
    observations = rng.normal(0.0, 1.0, (args.ticks, policy.obs_size)).astype(np.float32) * 0.05
    policy_times = np.empty(args.ticks)
    for k in range(args.ticks):  # the policy alone (for a residual: the classical base and the networks)
        t0 = time.perf_counter()
        policy(observations[k])
        policy_times[k] = time.perf_counter() - t0
    policy_times *= 1e3
    # the observer alone (for the Kalman observer: the filter's command, update and prediction), fed as the loop's
    observer = loop.observer  # the loop's own, started afresh
    observer.reset(float(ticks[0] - ages[0]), (float(readings[0, 0]), float(readings[0, 1])))
    tilts = rng.uniform(-0.1, 0.1, (args.ticks, 2))
    observer_times = np.empty(args.ticks)
    for k in range(args.ticks):
        t0 = time.perf_counter()
        sample = ((float(readings[k, 0]), float(readings[k, 1])), float(ticks[k] - ages[k]))
        observer.observe(sample, (0.0, 0.0), (0.0, 0.0), (float(tilts[k, 0]), float(tilts[k, 1])), (0.0, 0.0),
                         now=float(ticks[k]))  # fmt: skip
        observer_times[k] = time.perf_counter() - t0
    observer_times *= 1e3
    res = {"bundle": str(args.bundle), "networks": policy.meta.get("ensemble", 1), "ticks": args.ticks,
           "p50_ms": float(np.percentile(times, 50)), "p99_ms": float(np.percentile(times, 99)),
           "max_ms": float(times.max()), "policy_p50_ms": float(np.percentile(policy_times, 50)),
           "policy_p99_ms": float(np.percentile(policy_times, 99)), "observer": policy.estimator,
           "observer_p50_ms": float(np.percentile(observer_times, 50)),
           "observer_p99_ms": float(np.percentile(observer_times, 99))}  # fmt: skip
    if args.json:
        print(json.dumps(res))
    else:
        print(f"{args.bundle} ({res['networks']} network(s)): deploy tick compute (obs → ONNX → IK → safety → bytes), "
              f"{args.ticks:,} ticks: p50 {res['p50_ms']:.3f} ms, p99 {res['p99_ms']:.3f} ms (target ≤ 1 ms), "
              f"max {res['max_ms']:.3f} ms; the policy alone: p50 {res['policy_p50_ms']:.3f} ms, "
              f"p99 {res['policy_p99_ms']:.3f} ms; the {policy.estimator} observer alone: p50 "
              f"{res['observer_p50_ms']:.3f} ms, p99 {res['observer_p99_ms']:.3f} ms")


if __name__ == "__main__":
    main()
