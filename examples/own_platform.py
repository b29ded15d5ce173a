"""Your own servo platform from four measurements: a geometry file with a ``[symmetric]`` table, its inverse
kinematics at home and tilted, and the shipped PID + Kalman (its gains adapted to the build) balancing a ball
on it in simulation. Writes the file to ``out/my_platform.toml``; pass it as ``--geometry`` to any command.

    python examples/own_platform.py --base-radius 110 --platform-radius 85 --rod 170
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import gymnasium as gym
import numpy as np

import stewart_gym  # noqa: F401  (registers the env ids)
from stewart_gym import ServoCalibration, inverse_kinematics, load_geometry
from stewart_gym.cli.common import Parser, int_at_least
from stewart_gym.control import classical_controller, shipped_design
from stewart_gym.errors import ConfigError
from stewart_gym.outputs import output_file

TOML = """name = "my-platform"
length_unit = "mm"
angle_unit = "deg"
horn_length = {horn}
rod_length = {rod}
servo_angle_range = [-30, 60]
plate_size = [{plate}, {plate}]

[symmetric]
base_radius = {base_radius}
base_pair_angle = {base_pair_angle}
platform_radius = {platform_radius}
platform_pair_angle = {platform_pair_angle}
"""


def main(argv: list[str] | None = None) -> None:
    parser = Parser.for_script(__doc__)
    parser.add_argument("--base-radius", type=float, default=110.0, help="servo shafts' circle, mm")
    parser.add_argument("--base-pair-angle", type=float, default=30.0, help="between a pair's shafts, degrees")
    parser.add_argument("--platform-radius", type=float, default=85.0, help="rod ends' circle on the plate, mm")
    parser.add_argument("--platform-pair-angle", type=float, default=20.0, help="between a pair's rod ends, degrees")
    parser.add_argument("--horn", type=float, default=25.0, help="horn length, mm")
    parser.add_argument("--rod", type=float, default=170.0, help="rod length, mm")
    parser.add_argument("--plate", type=float, default=320.0, help="square plate's side, mm")
    parser.add_argument("--episodes", type=int_at_least(1), default=3, help="episodes of the balancing check")
    parser.add_argument("--out", default="out/my_platform.toml", help="the geometry file to write")
    parser.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    args = parser.parse_args(argv)

    try:
        path = output_file(args.out, suffixes=(".toml",), overwrite=args.overwrite)
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=path.parent) as scratch:  # written where it goes once it describes a build
            draft = Path(scratch) / path.name
            draft.write_text(TOML.format(**vars(args)))
            try:
                geometry = load_geometry(draft)
            except ConfigError as exc:  # named as the file it would have been
                raise ConfigError(str(exc).replace(str(draft), str(path))) from None
            draft.replace(path)
    except ConfigError as exc:  # a measurement that describes no platform: say which, in one line
        sys.exit(f"error: {exc}")
    except OSError as exc:
        sys.exit(f"error: cannot write {args.out}: {exc.strerror or exc}")
    print(f"{path}: home height {1e3 * geometry.home_height:.2f} mm")

    calibration = ServoCalibration.default(geometry)
    for label, pose in (("home", [0, 0, 0, 0, 0, 0]), ("roll 5°", [0, 0, 0, np.radians(5), 0, 0])):
        ik = inverse_kinematics(geometry, np.array(pose, dtype=float))
        pulses = calibration.pulse_widths(ik.servo_angles)
        print(f"{label}: servo angles {np.round(np.degrees(ik.servo_angles), 1).tolist()} °, "
              f"pulses {np.round(pulses).astype(int).tolist()} µs")  # fmt: skip

    controller = classical_controller("pid", shipped_design("pid-kalman"), geometry=geometry)
    env = gym.make("StewartBallBalance-v0", geometry=str(path), estimator="kalman", randomize=True)
    successes = 0
    for episode in range(args.episodes):
        obs, info = env.reset(seed=episode)
        controller.reset()
        done = False
        while not done:
            obs, reward, terminated, truncated, info = env.step(controller.predict(obs)[0])
            done = terminated or truncated
        successes += bool(info["is_success"])
    print(f"PID + Kalman on {geometry.name}: success {successes}/{args.episodes}")
    env.close()


if __name__ == "__main__":
    main()
