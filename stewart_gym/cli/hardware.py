"""``stewart-gym`` hardware commands: deploy (the control loop) and calibrate (servo trims)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from stewart_gym.calibration import ServoCalibration
from stewart_gym.cli.common import (
    EXIT_CODES_HELP,
    EXIT_FAILED,
    EXIT_OK,
    MAX_SEED,
    add_backend,
    add_estimator,
    add_geometry,
    add_twin,
    bounded_float,
    int_at_least,
    output_file,
    positive_float,
    twin_tables,
)
from stewart_gym.cli.learning import ENV_CHOICES
from stewart_gym.envs.targets import TRAJECTORIES
from stewart_gym.errors import ConfigError
from stewart_gym.outputs import make_parent

__all__ = ["register"]

PROTOCOL_CHOICES = ("maestro", "ssc32", "line")


def cmd_deploy(args: argparse.Namespace) -> int:
    """Run a policy on servos at a fixed rate (sensor → policy → IK → safety → serial). Every input is checked
    before the port opens. Every way the run ends (its --duration, Ctrl-C, SIGTERM, SIGHUP, an error, a device
    failure) drives the servos home and prints the summary, which says whether the board confirmed the home
    pulses; a stop signal N exits 128 + N (Ctrl-C 130, SIGTERM 143, SIGHUP 129)."""
    from stewart_gym.hardware.deploy_setup import DeployOptions, DeploySetup
    from stewart_gym.registry import deployable_policy, resolve_policy, same_geometry

    if args.twin and args.sensor != "sim":  # before the file is read: it has no use here
        raise ConfigError("--twin describes the simulated plant: it needs --sensor sim")
    if args.sensor != "sim" and (args.seed is not None or args.no_randomize):
        raise ConfigError(f"{'--seed' if args.seed is not None else '--no-randomize'} sets the simulated plant: it "
                          "needs --sensor sim (a real platform has no seed)")  # fmt: skip
    source = resolve_policy(args.policy, args.env, args.geometry, args.estimator)
    policy = deployable_policy(source)
    if args.env and policy.env_id != args.env:
        raise ConfigError(f"{args.policy} was exported for {policy.env_id}, not {args.env}; leave out --env")
    if args.geometry and not same_geometry(args.geometry, policy.geometry):
        raise ConfigError(f"{args.policy} was made for geometry {policy.geometry.name!r}, not {args.geometry!r}")
    rate = float(policy.control_hz) if args.rate is None else args.rate  # the rate it was trained at, by default
    if policy.control_hz != round(rate):
        print(f"note: the policy was trained at {policy.control_hz} Hz and runs at {rate:g} Hz", flush=True)
    options = DeployOptions(port=args.port, protocol=args.protocol, baudrate=args.baudrate, sensor=args.sensor,
                            camera_config=args.camera_config, calibration=args.calibration, backend=args.backend,
                            rate_hz=rate, duration_s=args.duration, watchdog_s=args.watchdog_ms / 1000,
                            max_step_us=args.max_step_us, trajectory=args.trajectory, log=args.log,
                            overwrite=args.overwrite, seed=args.seed or 0, randomize=not args.no_randomize,
                            write_only=args.write_only, answer_timeout_s=args.answer_timeout_ms / 1000,
                            twin=twin_tables(args.twin))  # fmt: skip
    setup = DeploySetup(policy, options, say=lambda line: print(line, flush=True))
    summary = setup.run()
    print(summary.text(), flush=True)
    print(f"log: {setup.log}", flush=True)
    return summary.exit_code


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Find servo trims: step one servo at a time; keys on stdin: + / - (trim), n (next servo), q (save and quit)."""
    from stewart_gym.hardware.deploy_setup import load_calibration, port_settings
    from stewart_gym.hardware.serial_controllers import open_controller
    from stewart_gym.hardware.trim import calibration_toml, find_trims
    from stewart_gym.presets import load_geometry

    out = output_file(args.out, suffixes=(".toml",), overwrite=args.overwrite)  # (a calibration holds hand-set trims)
    geometry = load_geometry(args.geometry)
    calibration, hw = load_calibration(args.calibration, geometry, used_for=f"--geometry {args.geometry}")
    port, protocol, baudrate = port_settings(args.port, args.protocol, args.baudrate, hw)
    nominal = ServoCalibration.default(geometry).neutral_us  # untrimmed: 1500 µs, or the home leg length's pulse
    controller = open_controller(protocol, port, calibration.channels, baudrate,
                                 (calibration.min_us, calibration.max_us), args.calibration or "the default calibration")
    if geometry.is_rotary:  # what each horn should show: the trim is right when it stands at this angle
        angles = [math.degrees(a) for a in calibration.home_angle]
        shown = f"{angles[0]:.1f}°" if max(angles) - min(angles) < 0.05 else ", ".join(f"{a:.1f}°" for a in angles)
        print(f"home angle of each horn on {geometry.name}: {shown} above horizontal", flush=True)
    try:
        result = find_trims(controller, calibration, sys.stdin, args.step, say=lambda s: print(s, flush=True),
                            nominal_us=nominal)  # fmt: skip
    finally:
        controller.close()
    if sys.platform != "win32" and not Path(port).is_absolute() and Path(port).exists():  # a link in a folder:
        # kept wherever deploy runs from (a Windows port, COM3, is a device name, never a path)
        port = str(Path(port).absolute())
    written = {"port": port, "protocol": protocol, "baudrate": baudrate}
    text = calibration_toml(result.calibration, written, geometry=args.geometry, folder=out.parent)
    make_parent(out).write_text(text, encoding="utf-8")
    print(f"calibration written to {out} (geometry {geometry.name}, port {port}, protocol {protocol})")
    return EXIT_OK


def cmd_virtual_device(args: argparse.Namespace) -> int:
    """A virtual servo board with the simulated platform attached, on a pseudo-terminal: deploy and calibrate talk
    to it as to the real board. Runs until Ctrl-C (SIGINT), SIGTERM or SIGHUP, then prints what it saw (exit 0)."""
    import signal

    if sys.platform == "win32":
        raise ConfigError("virtual-device serves a pseudo-terminal, which Windows has not: run it on Linux or macOS, "
                          "or in WSL (Windows Subsystem for Linux) with the rest of the tutorial")  # fmt: skip
    from stewart_gym.hardware.deploy_setup import load_calibration
    from stewart_gym.hardware.virtual_device import Faults, VirtualDevice, stream_camera_config
    from stewart_gym.presets import load_geometry

    if args.stall_sensor_after is not None and args.protocol != "line":
        raise ConfigError(f"--stall-sensor-after stops the ball reports, which only the line protocol's board sends; "
                          f"this board answers {args.protocol!r}: add --protocol line, or leave it out")  # fmt: skip
    faults = Faults(drop_rate=args.drop_rate, corrupt_rate=args.corrupt_rate,
                    stall_sensor_after_s=args.stall_sensor_after, latency_ms=args.latency_ms,
                    unplug_after_s=args.unplug_after, stop_reading_after_s=args.stop_reading_after,
                    read_bytes_per_s=args.read_rate)  # fmt: skip
    if args.link is not None and not args.link.strip():
        raise ConfigError("--link: give a path for the link (for example /tmp/stewart0), not an empty one")
    geometry = load_geometry(args.geometry)
    calibration, _ = load_calibration(args.calibration, geometry, used_for=f"--geometry {args.geometry}")
    if args.backend == "mujoco":
        import importlib.util

        if importlib.util.find_spec("mujoco") is None:
            raise ConfigError("--backend mujoco needs MuJoCo: pip install 'stewart_gym[mujoco]'")
    if args.camera_config_out is not None and not args.camera_stream:
        raise ConfigError("--camera-config-out writes the config that reads the camera stream: give --camera-stream "
                          "PIPE too")  # fmt: skip
    config_out = None if args.camera_config_out is None else output_file(args.camera_config_out, suffixes=(".toml",))
    if config_out is not None and config_out.exists() and not args.overwrite:
        raise ConfigError(f"--camera-config-out {config_out} exists (your own camera config?): give another path, or "
                          "--overwrite to replace it")  # fmt: skip
    camera = None
    if args.camera_stream:
        from stewart_gym.camera import camera_preset

        camera = camera_preset(args.camera)
    twin = twin_tables(args.twin)
    ours = config_out is not None and not config_out.exists()  # (an existing one is replaced only with --overwrite)
    if config_out is not None:  # before the board's link appears: a host may read it at once
        make_parent(config_out).write_text(stream_camera_config(camera, args.camera_stream).to_toml(), encoding="utf-8")
    put_back = None if args.leave_fallen_ball else args.put_ball_back_after
    try:
        device = VirtualDevice(args.protocol, args.backend, geometry, calibration, faults, seed=args.seed,
                               randomize=not args.no_randomize, link=args.link, env_id=args.env, camera=camera,
                               camera_stream=args.camera_stream, twin=twin, put_ball_back_after_s=put_back)  # fmt: skip
    except BaseException:
        if ours:  # no board reads that stream
            config_out.unlink(missing_ok=True)
        raise
    where = device.path + (f" (link {device.link})" if device.link else "")
    if config_out is not None:
        where += f"; the camera config that reads its stream in {config_out}"
    from stewart_gym.sim.engines import default_backend

    engine = default_backend() if args.backend == "auto" else args.backend  # the engine "auto" picked here
    print(f"virtual {args.protocol} board with {geometry.name}{' (the twin ' + args.twin + ')' if twin else ''} in "
          f"{engine} on {where}; Ctrl-C to stop",
          flush=True)  # fmt: skip
    stop = {"now": False}

    def on_signal(signum: int, frame: object) -> None:  # the board finishes its tick, then stops
        stop["now"] = True

    stopping = (signal.SIGINT, signal.SIGTERM, *((signal.SIGHUP,) if hasattr(signal, "SIGHUP") else ()))
    before = {num: signal.signal(num, on_signal) for num in stopping}
    try:
        summary = device.run(lambda: stop["now"])
    finally:
        for num, handler in before.items():
            signal.signal(num, handler)
    print(summary.text(), flush=True)
    return EXIT_OK


def cmd_camera_check(args: argparse.Namespace) -> int:
    """Find the plate and the ball: in one image (--image; prints the ball in plate mm, exit 1 if none), or in live
    frames from the config's camera or video, writing an annotated image to tune the colour range."""
    import json

    from stewart_gym.vision import CameraConfig, annotate, grab_frames, locate_ball, read_image, source_problem

    config = CameraConfig.from_toml(args.camera_config)
    out = output_file(args.out, suffixes=(".png", ".jpg"), overwrite=args.overwrite) if args.out is not None else None
    if out is not None and args.image and Path(args.image).resolve() == out.resolve():
        raise ConfigError(f"--out {args.out} is the --image it reads: give another file for the annotated image")
    import cv2

    if args.image:
        frames = [read_image(args.image)]
    else:
        from stewart_gym.errors import DeviceFailure
        from stewart_gym.hardware.camera_sensor import FIRST_FRAME_TIMEOUT_S

        try:
            opened, frames = grab_frames(config.source, args.frames, FIRST_FRAME_TIMEOUT_S)
        except TimeoutError:
            raise DeviceFailure(f"camera {config.source!r} delivered no frame within {FIRST_FRAME_TIMEOUT_S:g} s "
                                "(nothing writing to the pipe? a camera in use or hung?)") from None  # fmt: skip
        if not opened:
            problem = source_problem(config.source)  # a folder, or a file that is no video: the user's to fix
            if problem is not None:
                raise ConfigError(f"{args.camera_config}: {problem}")
            raise DeviceFailure(f"camera {config.source!r} cannot be opened (wrong index or path, or in use?)")
        if not frames:
            raise ConfigError(f"{args.camera_config}: camera {config.source!r} gave no frames (an empty video, or a "
                              f"stream that stalled for {FIRST_FRAME_TIMEOUT_S:g} s)")  # fmt: skip
    detections = [locate_ball(f, config) for f in frames]
    last = detections[-1]
    if out is None and not args.image:
        out = output_file("camera_check.png", suffixes=(".png",))
    if out is not None:
        if not cv2.imwrite(str(make_parent(out)), annotate(frames[-1], config, last)):
            raise ConfigError(f"{out}: the annotated image could not be written (check the folder and the name)")
    if args.json:
        result = last.as_dict()
        if not args.image:
            result["frames"], result["found"] = len(detections), sum(d.xy_mm is not None for d in detections)
        print(json.dumps(result))
    else:
        if len(detections) > 1:
            print(f"ball found in {sum(d.xy_mm is not None for d in detections)} of {len(detections)} frames")
        print(f"ball at ({last.xy_mm[0]:.1f}, {last.xy_mm[1]:.1f}) mm, {last.markers} markers"
              if last.xy_mm is not None else last.reason)  # fmt: skip
        if out is not None:
            print(f"annotated image: {out}")
    return EXIT_OK if last.xy_mm is not None else EXIT_FAILED


def add_port(p: argparse.ArgumentParser) -> None:
    """``--port``, ``--protocol`` and ``--baudrate`` of the commands that talk to the servo board."""
    p.add_argument("--port", help="serial port (default: [hardware] port of the calibration file)")
    p.add_argument("--protocol", choices=PROTOCOL_CHOICES,
                   help="the servo board's serial protocol (default: [hardware] protocol of the calibration file)")
    p.add_argument("--baudrate", type=int_at_least(300, 4_000_000),
                   help="serial speed (default: the calibration file's, else the protocol's own)")


def register(sub: Any) -> None:
    """Add the hardware subcommands to the ``stewart-gym`` parser."""
    p = sub.add_parser("deploy", help=cmd_deploy.__doc__, description=cmd_deploy.__doc__, epilog=EXIT_CODES_HELP)
    p.add_argument("--policy", default="shipped",
                   help="'shipped' (the default), 'shipped-residual', 'shipped-camera', 'pid', 'pid-kalman', 'lqr', "
                        "'lqr-pid', a bundle folder, a run folder or a gains .json")  # fmt: skip
    add_estimator(p, "the observer: lowpass or kalman (default: the bundle's; kalman for pid-kalman and lqr)")
    p.add_argument("--env", choices=ENV_CHOICES, help="which shipped policy (default balance)")
    p.add_argument("--geometry", help="which shipped policy or PID (default servo-hexapod); a bundle carries its own")
    add_port(p)
    p.add_argument("--sensor", choices=["sim", "panel", "camera"], default="sim",
                   help="where the ball position comes from: the simulated plant (a dry run), the board's touch panel "
                        "or a camera")  # fmt: skip
    p.add_argument("--camera-config", help="camera config TOML (--sensor camera; see stewart-gym camera-check)")
    add_backend(p, "physics engine of the simulated plant (--sensor sim; default: PyBullet if installed, else MuJoCo)")
    p.add_argument("--calibration", help="calibration TOML (trims, directions, limits, [hardware])")
    p.add_argument("--duration", type=positive_float, help="seconds (default: until Ctrl-C)")
    p.add_argument("--rate", type=bounded_float(0.0, 500.0, lo_open=True),
                   help="control rate, Hz (≤ 500; default: the rate the policy was trained at, 50 for the classical "
                        "controllers)")  # fmt: skip
    p.add_argument("--watchdog-ms", type=bounded_float(1.0, 10_000.0), default=100.0,
                   help="sensor data older than this sends the platform home")  # fmt: skip
    p.add_argument("--max-step-us", type=bounded_float(0.0, 1000.0, lo_open=True),
                   help="rate limit per channel per tick, µs (default 3000 µs/s ÷ rate: 60 at 50 Hz, just under "
                        "the reference servos' own speed)")  # fmt: skip
    p.add_argument("--trajectory", choices=TRAJECTORIES,
                   help="moving target of a track policy (default: the one it was trained on)")  # fmt: skip
    p.add_argument("--log", help="CSV log (default out/deploy_log_<date>-<time>.csv; never overwritten without --overwrite)")
    p.add_argument("--overwrite", action="store_true", help="allow --log to replace an existing file")
    p.add_argument("--seed", type=int_at_least(0, MAX_SEED), help="simulated plant's seed (--sensor sim; default 0)")
    p.add_argument("--no-randomize", action="store_true", help="nominal simulated plant (--sensor sim)")
    add_twin(p, "the simulated plant is this twin's platform, exactly (--sensor sim)")
    p.add_argument("--write-only", action="store_true",
                   help="the board's replies are not wired: do not ask it anything (a board that stops reading "
                        "then goes unnoticed, and homing is 'sent, not confirmed')")  # fmt: skip
    p.add_argument("--answer-timeout-ms", type=bounded_float(50.0, 60_000.0), default=500.0,
                   help="a board that leaves a position query unanswered this long has stopped reading, or reads "
                        "too slowly: a device failure (default 500)")  # fmt: skip
    p.set_defaults(func=cmd_deploy)

    p = sub.add_parser("virtual-device", help=cmd_virtual_device.__doc__, description=cmd_virtual_device.__doc__)
    p.add_argument("--protocol", choices=PROTOCOL_CHOICES, default="maestro", help="the serial protocol to answer")
    add_backend(p, "physics engine of the twin (default: PyBullet if installed, else MuJoCo)")
    add_geometry(p)
    p.add_argument("--calibration", help="calibration TOML: the board's channels and limits")
    p.add_argument("--link", help="make this path a symlink to the pty (e.g. /tmp/stewart0)")
    p.add_argument("--env", choices=ENV_CHOICES, default="StewartBallBalance-v0", help="whose task places the ball")
    p.add_argument("--seed", type=int_at_least(0, MAX_SEED), default=0,
                   help="the twin's episode: ball start, physics, noise")  # fmt: skip
    p.add_argument("--no-randomize", action="store_true", help="nominal physics")
    add_twin(p, "the platform has exactly this twin's parameters (TOML; see stewart-gym sysid): a 'real' platform "
                "whose parameters the host does not know")
    p.add_argument("--drop-rate", type=bounded_float(0.0, 1.0), default=0.0, help="fraction of received bytes lost")
    p.add_argument("--corrupt-rate", type=bounded_float(0.0, 1.0), default=0.0,
                   help="fraction of received bytes with a bit flipped")  # fmt: skip
    p.add_argument("--stall-sensor-after", type=bounded_float(0.0, 1e6), metavar="S",
                   help="stop the ball reports S seconds after the first frame (line protocol)")  # fmt: skip
    p.add_argument("--latency-ms", type=bounded_float(0.0, 1000.0), default=0.0, help="added latency, both ways")
    p.add_argument("--unplug-after", type=bounded_float(0.0, 1e6), metavar="S",
                   help="disappear S seconds after the first frame")  # fmt: skip
    p.add_argument("--stop-reading-after", type=bounded_float(0.0, 1e6), metavar="S",
                   help="stop reading the host's bytes S seconds after the first frame (a hung board)")  # fmt: skip
    p.add_argument("--read-rate", type=bounded_float(1.0, 1e7), metavar="BYTES_PER_S",
                   help="read at most this many bytes a second (a board too slow for the frames)")  # fmt: skip
    fallen = p.add_mutually_exclusive_group()
    fallen.add_argument("--put-ball-back-after", type=bounded_float(0.0, 1e6), default=2.0, metavar="S",
                        help="put the ball back, at rest at the plate's centre, S seconds (half a second or more) "
                             "after it falls off, as a person at the bench would (default 2)")  # fmt: skip
    fallen.add_argument("--leave-fallen-ball", action="store_true", help="leave the ball where it falls")
    p.add_argument("--camera-stream", metavar="PIPE",
                   help="also stream the twin's camera view (MJPEG) into this named pipe, for deploy --sensor camera")
    p.add_argument("--camera", choices=("pixy2", "webcam30", "global90"), default="pixy2",
                   help="the streamed camera's preset: resolution, field of view, frame rate (default pixy2)")
    p.add_argument("--camera-config-out", metavar="FILE",
                   help="write the camera config that reads the stream, for --camera-config of identify and deploy")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --camera-config-out file")
    p.set_defaults(func=cmd_virtual_device, backend="auto")

    p = sub.add_parser("camera-check", help=cmd_camera_check.__doc__, description=cmd_camera_check.__doc__)
    p.add_argument("--camera-config", required=True, help="camera config TOML ([camera], [markers], [ball])")
    p.add_argument("--image", help="one image file to read instead of the camera")
    p.add_argument("--frames", type=int_at_least(1, 10_000), default=30, help="live frames to grab (default 30)")
    p.add_argument("--out", help="annotated image (.png/.jpg; default camera_check.png for live frames, replaced each "
                                 "run)")  # fmt: skip
    p.add_argument("--overwrite", action="store_true", help="allow --out to replace an existing file")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_camera_check)

    p = sub.add_parser("calibrate", help=cmd_calibrate.__doc__, description=cmd_calibrate.__doc__)
    add_geometry(p)
    p.add_argument("--port", help="serial port of the servo board (default: [hardware] port of --calibration)")
    p.add_argument("--protocol", choices=PROTOCOL_CHOICES,
                   help="the board's serial protocol (default: the [hardware] protocol of --calibration)")
    p.add_argument("--baudrate", type=int_at_least(300, 4_000_000),
                   help="serial speed (default: the protocol's own)")
    p.add_argument("--calibration", help="start from this calibration TOML")
    p.add_argument("--step", type=bounded_float(0.0, 100.0, lo_open=True), default=5.0, help="µs per key press")
    p.add_argument("--out", default="calibration.toml", help="the calibration TOML to write")
    p.add_argument("--overwrite", action="store_true", help="allow --out to replace an existing calibration")
    p.set_defaults(func=cmd_calibrate)

