"""Camera sensing: the vision pipeline's speed and accuracy on frames rendered from the simulator.

Run: ``.venv/bin/python bench/bench_camera.py [--frames 200] [--json]``.

Renders ``--frames`` 640×480 images of the reference plate (the webcam preset: 60° field of view, 0.5 m above
the plate) with the ball at random positions and the plate tilted by up to 10° in any direction, then runs
:func:`~stewart_gym.vision.locate_ball` on them as a stream (one core; the median and the 95th percentile of
the per-frame time, the first frame, which builds the detectors, left out) and compares its result with the
ball's true position.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from stewart_gym.camera import CAMERA_PRESETS  # noqa: E402
from stewart_gym.cli.common import int_at_least
from stewart_gym.kinematics import inverse_kinematics  # noqa: E402
from stewart_gym.sim import StewartSim  # noqa: E402
from stewart_gym.vision import CameraConfig, locate_ball  # noqa: E402


def main() -> None:
    import cv2

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int_at_least(2), default=200)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    cam = CAMERA_PRESETS["webcam30"]
    config = CameraConfig(fov_deg=cam.fov_deg)
    rng = np.random.default_rng(0)
    times, errors, frames = [], [], []
    with StewartSim(ball=True) as sim:
        for _ in range(args.frames):
            sim.reset()
            angle, size = rng.uniform(0, 2 * math.pi), math.radians(10) * math.sqrt(rng.uniform())
            ik = inverse_kinematics(sim.geometry, np.array([0, 0, 0, size * math.cos(angle), size * math.sin(angle), 0]))
            sim.command(sim.calibration.pulse_widths(ik.servo_angles))
            for _ in range(20):
                sim.step()
            sim.place_ball(rng.uniform(-0.125, 0.125, 2))
            frames.append((sim.camera_image(cam), np.array(sim.ball_position()[:2]) * 1e3))
    for image, truth in frames:  # a stream of frames, as from a camera: each processed once, timed
        t0 = time.perf_counter()
        d = locate_ball(image, config)
        times.append(time.perf_counter() - t0)
        errors.append(float(np.hypot(*(np.array(d.xy_mm) - truth))) if d.xy_mm is not None else math.inf)
    times = times[1:]
    res = {"frames": args.frames, "resolution": list(cam.resolution),
           "ms_per_frame_median": round(float(np.median(times)) * 1e3, 3),
           "ms_per_frame_p95": round(float(np.percentile(times, 95)) * 1e3, 3),
           "rms_error_mm": round(float(np.sqrt(np.mean(np.square(errors)))), 4),
           "max_error_mm": round(float(np.max(errors)), 4)}  # fmt: skip
    if args.json:
        print(json.dumps(res))
        return
    print(f"vision pipeline, {args.frames} rendered {cam.resolution[0]}×{cam.resolution[1]} frames, one core: "
          f"{res['ms_per_frame_median']:.2f} ms per frame (p95 {res['ms_per_frame_p95']:.2f} ms; target ≤ 5 ms); "
          f"error RMS {res['rms_error_mm']:.3f} mm, worst {res['max_error_mm']:.3f} mm (targets 1 and 3 mm)")


if __name__ == "__main__":
    main()
