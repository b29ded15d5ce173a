"""``stewart-gym`` hardware commands: deploy (the control loop) and calibrate (servo trims)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.calibration import ServoCalibration
from stewart_gym.cli.common import (
    EXIT_CODES_HELP,
    EXIT_FAILED,
    EXIT_OK,
    add_backend,
    add_estimator,
    add_geometry,
    bounded_float,
    int_at_least,
    output_file,
    positive_float,
)
from stewart_gym.cli.learning import ENV_CHOICES
from stewart_gym.envs.targets import TRAJECTORIES
from stewart_gym.errors import ConfigError

__all__ = ["register"]

PROTOCOL_CHOICES = ("maestro", "ssc32", "line")


def _load_calibration(path: str | None, geometry: Any) -> tuple[ServoCalibration, dict]:
    """The calibration for ``geometry`` (trims, directions, limits from ``path`` if given) and its [hardware].

    A calibration file that names another geometry is refused, naming both.
    """
    from stewart_gym.calibration import CalibrationError, hardware_settings
    from stewart_gym.presets import load_geometry
    from stewart_gym.registry import same_geometry
    from stewart_gym.tomlio import read_toml

    geo = load_geometry(geometry)
    if not path:
        return ServoCalibration.default(geo), {}
    declared = read_toml(path, CalibrationError).get("geometry")
    if declared is not None and not same_geometry(declared, geo):
        raise ConfigError(f"{path} is a calibration for geometry {declared!r}, but the policy was made for "
                          f"{geo.name!r}: calibrate this build with --geometry, or deploy a policy made for it")  # fmt: skip
    return ServoCalibration.from_toml(path, geo), hardware_settings(path)


def _port_settings(args: argparse.Namespace, hw: dict) -> tuple[str, str, int | None]:
    port = args.port or hw.get("port")
    if not port:
        raise ConfigError("no serial port: give --port, or a calibration file with [hardware] port")
    return str(port), args.protocol or hw.get("protocol", "maestro"), args.baudrate or hw.get("baudrate")


def _new_log_name() -> str:
    """deploy_log_<date>-<time>.csv in the current folder, with -2, -3, … if that exists: never an old log."""
    import time

    stem = f"deploy_log_{time.strftime('%Y%m%d-%H%M%S')}"
    name, k = f"{stem}.csv", 1
    while Path(name).exists():
        k += 1
        name = f"{stem}-{k}.csv"
    return name


def cmd_deploy(args: argparse.Namespace) -> int:
    """Run a policy on servos at a fixed rate (sensor → policy → IK → safety → serial)."""
    from stewart_gym.actions import ActionMapper
    from stewart_gym.envs import ENV_IDS
    from stewart_gym.envs.task import load_task
    from stewart_gym.hardware.deploy import DEFAULT_SLEW_US_PER_S, DeployConfig, DeployLoop, PanelSensor, SimulatedPlant
    from stewart_gym.hardware.serial_controllers import LineController, open_controller
    from stewart_gym.registry import deployable_policy, resolve_policy, same_geometry
    from stewart_gym.sensing import ObservationBuilder

    # everything the user gave is checked before the port opens
    source = resolve_policy(args.policy, args.env, args.geometry, args.estimator)
    policy = deployable_policy(source)
    env_id, geometry = policy.env_id, policy.geometry
    if args.env and env_id != args.env:
        raise ConfigError(f"{args.policy} was exported for {env_id}, not {args.env}; leave out --env")
    if args.geometry and not same_geometry(args.geometry, geometry):
        raise ConfigError(f"{args.policy} was made for geometry {geometry.name!r}, not {args.geometry!r}")
    if policy.observation_layout != ObservationBuilder.LAYOUT_VERSION:
        raise ConfigError(f"{args.policy} was exported for observation layout {policy.observation_layout}; this "
                          f"version builds layout {ObservationBuilder.LAYOUT_VERSION}: re-export it")  # fmt: skip
    if policy.control_hz != round(args.rate):
        print(f"note: the policy was trained at {policy.control_hz} Hz and runs at {args.rate:g} Hz", flush=True)
    calibration, hw = _load_calibration(args.calibration, geometry)
    port, protocol, baudrate = _port_settings(args, hw)
    if args.sensor == "sim":
        import importlib.util

        if importlib.util.find_spec("pybullet") is None or importlib.util.find_spec("gymnasium") is None:
            raise ConfigError("--sensor sim needs the simulator: pip install 'stewart_gym[sim]' (or use --sensor panel)")
        if args.backend == "mujoco" and importlib.util.find_spec("mujoco") is None:
            raise ConfigError("--backend mujoco needs MuJoCo: pip install 'stewart_gym[mujoco]'")
    elif args.backend:
        raise ConfigError("--backend chooses the simulated plant's engine: it needs --sensor sim")
    camera_config = None
    if args.sensor == "camera":
        if not args.camera_config:
            raise ConfigError("--sensor camera needs --camera-config FILE (see stewart-gym camera-check)")
        from stewart_gym.vision import CameraConfig

        camera_config = CameraConfig.from_toml(args.camera_config)
    elif args.camera_config:
        raise ConfigError("--camera-config goes with --sensor camera")
    if args.sensor == "panel" and protocol != "line":
        raise ConfigError("--sensor panel needs --protocol line (the Arduino sketch reports the panel)")
    task_kwargs = {k: v for k, v in policy.meta.get("env_kwargs", {}).items() if k == "trajectory"}
    if args.trajectory:
        task_kwargs["trajectory"] = args.trajectory
    if env_id not in ENV_IDS:
        raise ConfigError(f"{args.policy} was exported for {env_id!r}, which is not an env of this version")
    task = load_task(ENV_IDS[env_id][0], **task_kwargs)
    if args.trajectory and not task.moving_target:
        raise ConfigError(f"--trajectory needs a track policy; {args.policy} balances ({env_id})")
    log = args.log or _new_log_name()
    output_file(log, suffixes=(".csv",), overwrite=args.overwrite)
    mapper = ActionMapper(geometry, calibration, policy.action_mode, max_tilt=policy.max_tilt)
    config = DeployConfig(rate_hz=args.rate, duration_s=args.duration, watchdog_s=args.watchdog_ms / 1000,
                          max_step_us=args.max_step_us or DEFAULT_SLEW_US_PER_S / args.rate, log_path=log)  # fmt: skip
    task.reset(np.random.default_rng(args.seed), None)  # the target only: no disturbances on real hardware

    controller = open_controller(protocol, port, calibration.channels, baudrate)
    if args.sensor == "panel":
        assert isinstance(controller, LineController)
        sensor = PanelSensor(controller)
    elif args.sensor == "camera":
        from stewart_gym.hardware.camera_sensor import CameraSensor

        try:
            sensor = CameraSensor(camera_config)  # type: ignore[arg-type]
        except BaseException:
            controller.close()
            raise
    else:
        try:
            sensor = SimulatedPlant(env_id, seed=args.seed, randomize=not args.no_randomize, geometry=geometry,
                                    backend=args.backend or "pybullet")  # fmt: skip
        except BaseException:
            controller.close()
            raise
    if task.moving_target:
        print(f"tracking a {getattr(task, 'current_trajectory', 'moving')} target ({env_id})", flush=True)
    plant = sensor if isinstance(sensor, SimulatedPlant) else None
    try:
        summary = DeployLoop(policy, mapper, controller, sensor, config, task.target, plant=plant).run()
    finally:
        if args.sensor == "camera":
            sensor.close()  # type: ignore[union-attr]
    if args.sensor == "camera":
        summary.message += f"; camera: ball found in {sensor.found} of {sensor.frames} frames"  # type: ignore[union-attr]
    if isinstance(sensor, SimulatedPlant) and sensor.final_error_mm is not None:
        summary.message += f"; simulated ball {sensor.final_error_mm:.1f} mm from the centre"
    print(summary.text())
    print(f"log: {log}")
    return summary.exit_code


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Find servo trims: step one servo at a time; keys on stdin: + / - (trim), n (next servo), q (save and quit)."""
    from stewart_gym.hardware.serial_controllers import open_controller
    from stewart_gym.hardware.trim import calibration_toml, find_trims
    from stewart_gym.presets import load_geometry

    out = output_file(args.out, suffixes=(".toml",))
    geometry = load_geometry(args.geometry)
    calibration, hw = _load_calibration(args.calibration, geometry)
    port, protocol, baudrate = _port_settings(args, hw)
    nominal = ServoCalibration.default(geometry).neutral_us  # untrimmed: 1500 µs, or the home leg length's pulse
    controller = open_controller(protocol, port, calibration.channels, baudrate)
    try:
        result = find_trims(controller, calibration, sys.stdin, args.step, say=lambda s: print(s, flush=True),
                            nominal_us=nominal)  # fmt: skip
    finally:
        controller.close()
    out.write_text(calibration_toml(result.calibration, {"port": port, "protocol": protocol, "baudrate": baudrate},
                                    geometry=args.geometry))  # fmt: skip
    print(f"calibration written to {out} (geometry {geometry.name}, port {port}, protocol {protocol})")
    return EXIT_OK


def cmd_virtual_device(args: argparse.Namespace) -> int:
    """A virtual servo board with the simulated platform attached, on a pseudo-terminal: deploy and calibrate talk
    to it as to the real board. Runs until Ctrl-C (SIGINT) or SIGTERM, then prints what it saw."""
    import signal

    from stewart_gym.hardware.virtual_device import Faults, VirtualDevice
    from stewart_gym.presets import load_geometry

    faults = Faults(drop_rate=args.drop_rate, corrupt_rate=args.corrupt_rate,
                    stall_sensor_after_s=args.stall_sensor_after, latency_ms=args.latency_ms,
                    unplug_after_s=args.unplug_after)  # fmt: skip
    geometry = load_geometry(args.geometry)
    calibration, _ = _load_calibration(args.calibration, geometry)
    if args.backend == "mujoco":
        import importlib.util

        if importlib.util.find_spec("mujoco") is None:
            raise ConfigError("--backend mujoco needs MuJoCo: pip install 'stewart_gym[mujoco]'")
    stop = {"now": False}

    def on_signal(signum: int, frame: object) -> None:
        stop["now"] = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    camera = None
    if args.camera_stream:
        from stewart_gym.camera import camera_preset

        camera = camera_preset(args.camera)
    device = VirtualDevice(args.protocol, args.backend, geometry, calibration, faults, seed=args.seed,
                           randomize=not args.no_randomize, link=args.link, env_id=args.env, camera=camera,
                           camera_stream=args.camera_stream)  # fmt: skip
    where = device.path + (f" (link {device.link})" if device.link else "")
    print(f"virtual {args.protocol} board with {geometry.name} in {args.backend} on {where}; Ctrl-C to stop",
          flush=True)  # fmt: skip
    summary = device.run(lambda: stop["now"])
    print(summary.text(), flush=True)
    return EXIT_OK


def cmd_camera_check(args: argparse.Namespace) -> int:
    """Find the plate and the ball: in one image (--image; prints the ball in plate mm, exit 1 if none), or in live
    frames from the config's camera or video, writing an annotated image to tune the colour range."""
    import json

    from stewart_gym.vision import CameraConfig, annotate, locate_ball

    config = CameraConfig.from_toml(args.camera_config)
    out = output_file(args.out, suffixes=(".png", ".jpg")) if args.out else None
    import cv2

    if args.image:
        if not Path(args.image).is_file():
            raise ConfigError(f"--image {args.image}: no such file")
        frame = cv2.imread(args.image)
        if frame is None:
            raise ConfigError(f"--image {args.image}: not an image OpenCV can read")
        frames = [frame]
    else:
        cap = cv2.VideoCapture(config.source)
        if not cap.isOpened():
            from stewart_gym.errors import DeviceFailure

            raise DeviceFailure(f"camera {config.source!r} cannot be opened (wrong index or path, or in use?)")
        frames = []
        for _ in range(args.frames):
            ok, frame = cap.read()
            if not ok:
                break
            frames.append(frame)
        cap.release()
        if not frames:
            raise ConfigError(f"camera {config.source!r} gave no frames")
    detections = [locate_ball(f, config) for f in frames]
    last = detections[-1]
    if out is None and not args.image:
        out = output_file("camera_check.png", suffixes=(".png",))
    if out is not None:
        cv2.imwrite(str(out), annotate(frames[-1], config, last))
    if args.json:
        result = last.as_dict()
        if not args.image:
            result["frames"], result["found"] = len(detections), sum(d.xy_mm is not None for d in detections)
        print(json.dumps(result))
    else:
        if len(detections) > 1:
            print(f"ball found in {sum(d.xy_mm is not None for d in detections)} of {len(detections)} frames")
        print(f"ball at ({last.xy_mm[0]:.1f}, {last.xy_mm[1]:.1f}) mm, {last.markers} markers"
              if last.xy_mm is not None else f"no ball: {last.reason}")  # fmt: skip
        if out is not None:
            print(f"annotated image: {out}")
    return EXIT_OK if last.xy_mm is not None else EXIT_FAILED


def register(sub: Any) -> None:
    """Add the hardware subcommands to the ``stewart-gym`` parser."""
    p = sub.add_parser("deploy", help=cmd_deploy.__doc__, description=cmd_deploy.__doc__, epilog=EXIT_CODES_HELP)
    p.add_argument("--policy", default="shipped", help="a bundle folder, 'shipped', 'pid', 'pid-kalman' or 'lqr'")
    add_estimator(p, "the observer: lowpass or kalman (default: the bundle's; kalman for pid-kalman and lqr)")
    p.add_argument("--env", choices=ENV_CHOICES, help="which shipped policy (default balance)")
    p.add_argument("--geometry", help="which shipped policy or PID (default servo-hexapod); a bundle carries its own")
    p.add_argument("--port", help="serial port (default: [hardware] port of the calibration file)")
    p.add_argument("--protocol", choices=PROTOCOL_CHOICES)
    p.add_argument("--baudrate", type=int_at_least(300, 4_000_000))
    p.add_argument("--sensor", choices=["sim", "panel", "camera"], default="sim")
    p.add_argument("--camera-config", help="camera config TOML (--sensor camera; see stewart-gym camera-check)")
    add_backend(p, "physics engine of the simulated plant (--sensor sim; default pybullet)")
    p.add_argument("--calibration", help="calibration TOML (trims, directions, limits, [hardware])")
    p.add_argument("--duration", type=positive_float, help="seconds (default: until Ctrl-C)")
    p.add_argument("--rate", type=bounded_float(0.0, 500.0, lo_open=True), default=50.0, help="control rate, Hz (≤ 500)")
    p.add_argument("--watchdog-ms", type=bounded_float(1.0, 10_000.0), default=100.0,
                   help="sensor data older than this sends the platform home")  # fmt: skip
    p.add_argument("--max-step-us", type=bounded_float(0.0, 1000.0, lo_open=True),
                   help="rate limit per channel per tick, µs (default 3000 µs/s ÷ rate: 60 at 50 Hz, just under "
                        "the reference servos' own speed)")  # fmt: skip
    p.add_argument("--trajectory", choices=TRAJECTORIES,
                   help="moving target of a track policy (default: the one it was trained on)")  # fmt: skip
    p.add_argument("--log", help="CSV log (default deploy_log_<date>-<time>.csv; never overwritten without --overwrite)")
    p.add_argument("--overwrite", action="store_true", help="allow --log to replace an existing file")
    p.add_argument("--seed", type=int_at_least(0), default=0, help="simulated plant's seed (--sensor sim)")
    p.add_argument("--no-randomize", action="store_true", help="nominal simulated plant")
    p.set_defaults(func=cmd_deploy)

    p = sub.add_parser("virtual-device", help=cmd_virtual_device.__doc__, description=cmd_virtual_device.__doc__)
    p.add_argument("--protocol", choices=PROTOCOL_CHOICES, default="maestro")
    add_backend(p, "physics engine of the twin (default pybullet)")
    add_geometry(p)
    p.add_argument("--calibration", help="calibration TOML: the board's channels and limits")
    p.add_argument("--link", help="make this path a symlink to the pty (e.g. /tmp/stewart0)")
    p.add_argument("--env", choices=ENV_CHOICES, default="StewartBallBalance-v0", help="whose task places the ball")
    p.add_argument("--seed", type=int_at_least(0), default=0, help="the twin's episode: ball start, physics, noise")
    p.add_argument("--no-randomize", action="store_true", help="nominal physics")
    p.add_argument("--drop-rate", type=bounded_float(0.0, 1.0), default=0.0, help="fraction of received bytes lost")
    p.add_argument("--corrupt-rate", type=bounded_float(0.0, 1.0), default=0.0,
                   help="fraction of received bytes with a bit flipped")  # fmt: skip
    p.add_argument("--stall-sensor-after", type=bounded_float(0.0, 1e6), metavar="S",
                   help="stop the ball reports S seconds after the first frame (line protocol)")  # fmt: skip
    p.add_argument("--latency-ms", type=bounded_float(0.0, 1000.0), default=0.0, help="added latency, both ways")
    p.add_argument("--unplug-after", type=bounded_float(0.0, 1e6), metavar="S",
                   help="disappear S seconds after the first frame")  # fmt: skip
    p.add_argument("--camera-stream", metavar="PIPE",
                   help="also stream the twin's camera view (MJPEG) into this named pipe, for deploy --sensor camera")
    p.add_argument("--camera", choices=("pixy2", "webcam30", "global90"), default="pixy2",
                   help="the streamed camera's preset: resolution, field of view, frame rate (default pixy2)")
    p.set_defaults(func=cmd_virtual_device, backend="pybullet")

    p = sub.add_parser("camera-check", help=cmd_camera_check.__doc__, description=cmd_camera_check.__doc__)
    p.add_argument("--camera-config", required=True, help="camera config TOML ([camera], [markers], [ball])")
    p.add_argument("--image", help="one image file to read instead of the camera")
    p.add_argument("--frames", type=int_at_least(1, 10_000), default=30, help="live frames to grab (default 30)")
    p.add_argument("--out", help="annotated image (.png/.jpg; default camera_check.png for live frames)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_camera_check)

    p = sub.add_parser("calibrate", help=cmd_calibrate.__doc__, description=cmd_calibrate.__doc__)
    add_geometry(p)
    p.add_argument("--port")
    p.add_argument("--protocol", choices=PROTOCOL_CHOICES)
    p.add_argument("--baudrate", type=int_at_least(300, 4_000_000))
    p.add_argument("--calibration", help="start from this calibration TOML")
    p.add_argument("--step", type=bounded_float(0.0, 100.0, lo_open=True), default=5.0, help="µs per key press")
    p.add_argument("--out", default="calibration.toml")
    p.set_defaults(func=cmd_calibrate)

