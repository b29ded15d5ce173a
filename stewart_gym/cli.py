"""The ``stewart-gym`` command line.

Every subcommand checks its arguments before it starts work, prints a user's
mistake as one ``error: …`` line and exits with a code that means something
(see :mod:`stewart_gym.cliutil`): 0 done, 1 user error or failed result, 2
device failure. ``--debug`` shows tracebacks.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stewart_gym.cliutil import (
    EXIT_FAILED,
    EXIT_OK,
    Parser,
    bounded_float,
    finite_float,
    int_at_least,
    output_dir,
    output_file,
    positive_float,
    run,
)
from stewart_gym.errors import ConfigError, UnreachableError
from stewart_gym.geometry import load_geometry, preset_names
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.servo import ServoCalibration

if TYPE_CHECKING:
    from stewart_gym.sim import StewartSim

__all__ = ["build_parser", "main"]

ENV_CHOICES = ("StewartBallBalance-v0", "StewartBallTrack-v0")
PROTOCOL_CHOICES = ("maestro", "ssc32", "line")
EXIT_CODES_HELP = ("exit codes: 0 done; 1 a user error (bad option, missing or malformed file) or a failed result "
                   "(unreachable pose, deploy that could not keep its rate); 2 a device failure (serial port missing, "
                   "unplugged or not answering)")  # fmt: skip


def _version() -> str:
    from stewart_gym import __version__

    return __version__


def _geometry_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--geometry", default="servo-hexapod", help=f"preset ({', '.join(preset_names())}) or TOML file")


def _pose_args(parser: argparse.ArgumentParser) -> None:
    """Six positional pose values, each a finite number."""
    for name, unit in (("x", "mm"), ("y", "mm"), ("z", "mm"), ("roll", "deg"), ("pitch", "deg"), ("yaw", "deg")):
        parser.add_argument(f"{name}_{unit}", type=finite_float, metavar=f"{name.upper()}_{unit.upper()}",
                            help=f"{name} ({unit}{', from home' if name == 'z' else ''})")  # fmt: skip


def _pose(args: argparse.Namespace) -> np.ndarray:
    """The pose of the six positionals, m and rad."""
    return np.array([args.x_mm * 1e-3, args.y_mm * 1e-3, args.z_mm * 1e-3, math.radians(args.roll_deg),
                     math.radians(args.pitch_deg), math.radians(args.yaw_deg)])  # fmt: skip


# ------------------------------------------------------------- kinematics
def cmd_ik(args: argparse.Namespace) -> int:
    """Inverse kinematics of one pose: leg lengths, servo angles, pulse widths. Exit 1 if it is unreachable."""
    from stewart_gym.analysis.cli import json_safe

    geo = load_geometry(args.geometry)
    pose = _pose(args)
    ik = inverse_kinematics(geo, pose)
    out: dict = {
        "geometry": geo.name,
        "pose": {"x_mm": args.x_mm, "y_mm": args.y_mm, "z_mm": args.z_mm,
                 "roll_deg": args.roll_deg, "pitch_deg": args.pitch_deg, "yaw_deg": args.yaw_deg},  # fmt: skip
        "reachable": bool(ik.reachable),
        "leg_lengths_mm": (ik.leg_lengths * 1e3).round(4).tolist(),
        "status": [int(s) for s in ik.status],
    }
    if geo.is_rotary:
        out["servo_angles_deg"] = np.degrees(ik.servo_angles).round(4).tolist()
        cal = ServoCalibration.default(geo)
        out["pulse_widths_us"] = cal.pulse_widths(ik.servo_angles, out_of_range="nan").round(2).tolist()
    if args.json:
        print(json.dumps(json_safe(out)))
    else:
        print(ik.explain())
        for key in ("leg_lengths_mm", "servo_angles_deg", "pulse_widths_us"):
            if key in out:
                print(f"  {key:18s} " + "  ".join(f"{v:9.3f}" for v in out[key]))
    return EXIT_OK if ik.reachable else EXIT_FAILED


def cmd_urdf(args: argparse.Namespace) -> int:
    """Write the mechanism and plate URDFs of a rotary geometry."""
    from stewart_gym.sim.urdf import write_urdfs

    geo = load_geometry(args.geometry)
    output_dir(args.out)
    for path in write_urdfs(args.out, geo):
        print(path)
    return EXIT_OK


def settle_at(sim: StewartSim, pose: np.ndarray, seconds: float = 1.0) -> np.ndarray:
    """Command ``pose`` through IK → pulses, step ``seconds``, and return the pulses sent."""
    ik = inverse_kinematics(sim.geometry, pose)
    if not ik.reachable:
        raise UnreachableError(ik.explain())
    pulses = sim.calibration.pulse_widths(ik.servo_angles, out_of_range="nan")
    if np.isnan(pulses).any():
        raise UnreachableError(f"{ik.explain()}, but a pulse width would leave its channel's limits")
    sim.command(pulses)
    for _ in range(int(round(seconds * sim.control_hz))):
        sim.step()
    return pulses


def cmd_render(args: argparse.Namespace) -> int:
    """Render the simulated mechanism at a pose to a PNG file (exit 1 if the pose is unreachable)."""
    import imageio.v3 as iio

    from stewart_gym.sim import StewartSim

    geo = load_geometry(args.geometry)
    pose = _pose(args)
    out = output_file(args.out, suffixes=(".png",))
    ik = inverse_kinematics(geo, pose) if geo.is_rotary else None
    if ik is not None and not ik.reachable:
        raise UnreachableError(ik.explain())
    with StewartSim(geo, ball=args.ball, render_mode="rgb_array", render_size=(args.width, args.height)) as sim:
        settle_at(sim, pose)
        if args.ball:
            sim.place_ball(np.zeros(2))
        iio.imwrite(out, sim.render())
        reached = sim.platform_pose()
        print(f"{out}: pose reached {np.round(reached[:3] * 1e3, 3).tolist()} mm, "
              f"{np.round(np.degrees(reached[3:]), 3).tolist()} deg")  # fmt: skip
    return EXIT_OK


# --------------------------------------------------------------- learning
def cmd_train(args: argparse.Namespace) -> int:
    """Train an agent with Stable-Baselines3 (PPO, SAC, TD3); hyperparameters from train/hyperparams/<algo>.yml."""
    from stewart_gym.training import TrainConfig, check_run_dir, train

    cfg = TrainConfig(env_id=args.env, algo=args.algo, hyperparams=args.hyperparams, run_dir=args.run_dir,
                      seed=args.seed, n_timesteps=args.timesteps, n_envs=args.n_envs, eval_freq=args.eval_freq,
                      eval_episodes=args.eval_episodes, resume=args.resume, progress_bar=not args.no_progress,
                      tensorboard=not args.no_tensorboard)  # fmt: skip
    check_run_dir(cfg, overwrite=args.overwrite)
    metrics = train(cfg, max_wall_s=None if args.max_minutes is None else args.max_minutes * 60)
    print(json.dumps(metrics, indent=2))
    return EXIT_OK


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Evaluate a policy (shipped, pid, a run folder, a model .zip, a bundle) on N seeded episodes."""
    from stewart_gym.analysis.cli import json_safe
    from stewart_gym.evaluation import evaluate, format_table
    from stewart_gym.registry import load_for_evaluation

    gif = None if args.gif is None else output_file(args.gif, suffixes=(".gif",))
    plot = None if args.plot is None else output_file(args.plot, suffixes=(".png",))
    source, policy, env_kwargs = load_for_evaluation(args.policy, args.env)
    env_id = args.env or source.env_id
    metrics = evaluate(env_id, policy, episodes=args.episodes, seed=args.seed, randomize=not args.no_randomize,
                       env_kwargs=env_kwargs)  # fmt: skip
    if gif or plot:
        _episode_figures(env_id, policy, env_kwargs, args.seed, not args.no_randomize, gif, plot, source.label)
    if args.json:
        print(json.dumps(json_safe(metrics)))
    else:
        print(format_table({source.label: metrics}))
    return EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: evaluate the shipped policy next to the PID baseline; write a GIF and a pulse-width plot."""
    from stewart_gym.analysis.cli import json_safe
    from stewart_gym.evaluation import evaluate, format_table
    from stewart_gym.registry import load_for_evaluation

    out = output_dir(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env_id = "StewartBallBalance-v0"
    results, loaded = {}, {}
    for name in ("shipped", "pid"):
        _, policy, env_kwargs = loaded[name] = load_for_evaluation(name, env_id)
        print(f"evaluating {name} on {args.episodes} seeded episodes with domain randomisation…", flush=True)
        results[name] = evaluate(env_id, policy, episodes=args.episodes, seed=args.seed, env_kwargs=env_kwargs)
    print()
    print(format_table(results))
    (out / "demo_metrics.json").write_text(json.dumps(json_safe(results), indent=2) + "\n")
    _, policy, env_kwargs = loaded["shipped"]
    _episode_figures(env_id, policy, env_kwargs, args.seed, True, out / "demo.gif", out / "demo_pulses.png", "shipped")
    print(f"\nwrote {out / 'demo.gif'}, {out / 'demo_pulses.png'} and {out / 'demo_metrics.json'}")
    return EXIT_OK


def _episode_figures(env_id: str, policy: object, env_kwargs: dict, seed: int, randomize: bool, gif: Path | None,
                     plot: Path | None, title: str) -> None:  # fmt: skip
    """Run one episode from the standard 100 mm offset; write its GIF and/or its ball-path and pulse-width plot."""
    import gymnasium as gym

    from stewart_gym.evaluation import SETTLING_OFFSET, plot_episode, run_episode, write_gif

    env = gym.make(env_id, randomize=randomize, render_mode="rgb_array" if gif else None, **env_kwargs)
    try:
        opts = {"ball_position": (SETTLING_OFFSET, 0.0), "ball_velocity": (0.0, 0.0)}
        log = run_episode(env, policy, seed, opts if env.unwrapped.task == "balance" else None, frames=bool(gif))
    finally:
        env.close()
    if gif:
        write_gif(log.frames, gif)
    if plot:
        plot_episode(log, plot, f"{env_id}, policy {title}")


def cmd_export(args: argparse.Namespace) -> int:
    """Export a policy (shipped, pid, a run folder, a model .zip) to a deployable ONNX/JSON bundle."""
    from stewart_gym.registry import export_policy, resolve_policy

    out = output_dir(args.out)
    source = resolve_policy(args.policy, args.env)
    if args.env and args.policy not in ("shipped", "pid") and source.env_id != args.env:
        raise ConfigError(f"{args.policy} was trained on {source.env_id}, not {args.env}; leave out --env")
    folder = export_policy(source, out)
    print(f"bundle written to {folder} ({source.env_id}, action mode {source.action_mode})")
    return EXIT_OK


# --------------------------------------------------------------- hardware
def _load_calibration(args: argparse.Namespace) -> tuple[ServoCalibration, dict]:
    from stewart_gym.servo import hardware_settings

    if args.calibration:
        return ServoCalibration.from_toml(args.calibration, "servo-hexapod"), hardware_settings(args.calibration)
    return ServoCalibration.default("servo-hexapod"), {}


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
    from stewart_gym.envs.targets import Fixed, make_trajectory
    from stewart_gym.hardware.deploy import DEFAULT_SLEW_US_PER_S, DeployConfig, DeployLoop, PanelSensor, SimulatedPlant
    from stewart_gym.hardware.devices import LineController, open_controller
    from stewart_gym.registry import deployable_policy, resolve_policy

    # everything the user gave is checked before the port opens
    source = resolve_policy(args.policy, args.env)
    policy = deployable_policy(source)
    env_id = policy.env_id
    if args.env and env_id != args.env:
        raise ConfigError(f"{args.policy} was exported for {env_id}, not {args.env}; leave out --env")
    calibration, hw = _load_calibration(args)
    port, protocol, baudrate = _port_settings(args, hw)
    if args.sensor == "panel" and protocol != "line":
        raise ConfigError("--sensor panel needs --protocol line (the Arduino sketch reports the panel)")
    tracking = env_id == "StewartBallTrack-v0"
    if args.trajectory and not tracking:
        raise ConfigError(f"--trajectory needs a track policy; {args.policy} balances ({env_id})")
    log = args.log or _new_log_name()
    output_file(log, suffixes=(".csv",), overwrite=args.overwrite)
    mapper = ActionMapper("servo-hexapod", calibration, policy.action_mode,
                          **({"max_tilt": float(policy.meta["env_kwargs"]["max_tilt"])}
                             if "max_tilt" in policy.meta.get("env_kwargs", {}) else {}))  # fmt: skip
    config = DeployConfig(rate_hz=args.rate, duration_s=args.duration, watchdog_s=args.watchdog_ms / 1000,
                          max_step_us=args.max_step_us or DEFAULT_SLEW_US_PER_S / args.rate, log_path=log)  # fmt: skip
    trajectory = args.trajectory or policy.meta.get("env_kwargs", {}).get("trajectory", "circle")
    target = make_trajectory(trajectory, np.random.default_rng(args.seed)) if tracking else Fixed()

    controller = open_controller(protocol, port, calibration.channels, baudrate)
    if args.sensor == "panel":
        assert isinstance(controller, LineController)
        sensor = PanelSensor(controller)
    else:
        try:
            sensor = SimulatedPlant(env_id, seed=args.seed, randomize=not args.no_randomize)
        except BaseException:
            controller.close()
            raise
    if tracking:
        print(f"tracking a {trajectory} target ({env_id})", flush=True)
    summary = DeployLoop(policy, mapper, controller, sensor, config, target).run()
    if isinstance(sensor, SimulatedPlant) and sensor.final_error_mm is not None:
        summary.message += f"; simulated ball {sensor.final_error_mm:.1f} mm from the centre"
    print(summary.text())
    print(f"log: {log}")
    return summary.exit_code


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Find servo trims: step one servo at a time; keys on stdin: + / - (trim), n (next servo), q (save and quit)."""
    from stewart_gym.hardware.devices import open_controller
    from stewart_gym.hardware.trim import calibration_toml, find_trims

    out = output_file(args.out, suffixes=(".toml",))
    calibration, hw = _load_calibration(args)
    port, protocol, baudrate = _port_settings(args, hw)
    controller = open_controller(protocol, port, calibration.channels, baudrate)
    try:
        result = find_trims(controller, calibration, sys.stdin, args.step, say=lambda s: print(s, flush=True))
    finally:
        controller.close()
    out.write_text(calibration_toml(result.calibration, {"port": port, "protocol": protocol, "baudrate": baudrate}))
    print(f"calibration written to {out} (port {port}, protocol {protocol})")
    return EXIT_OK


# ----------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="stewart-gym", description="Servo Stewart platform toolkit", epilog=EXIT_CODES_HELP)
    parser.add_argument("--version", action="version", version=f"stewart-gym {_version()}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of any error")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("ik", help=cmd_ik.__doc__, description=cmd_ik.__doc__)
    _geometry_arg(p)
    _pose_args(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_ik)

    p = sub.add_parser("urdf", help=cmd_urdf.__doc__, description=cmd_urdf.__doc__)
    _geometry_arg(p)
    p.add_argument("--out", default="urdf", help="folder (default urdf/)")
    p.set_defaults(func=cmd_urdf)

    p = sub.add_parser("render", help=cmd_render.__doc__, description=cmd_render.__doc__)
    _geometry_arg(p)
    _pose_args(p)
    p.add_argument("--out", required=True, help="PNG file")
    p.add_argument("--ball", action="store_true", help="put a ball on the plate")
    p.add_argument("--width", type=int_at_least(16, 4096), default=640, help="pixels")
    p.add_argument("--height", type=int_at_least(16, 4096), default=480, help="pixels")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("train", help=cmd_train.__doc__, description=cmd_train.__doc__)
    p.add_argument("--env", choices=ENV_CHOICES, default="StewartBallBalance-v0")
    p.add_argument("--algo", choices=["ppo", "sac", "td3"], default="ppo")
    p.add_argument("--hyperparams", help="YAML file (default train/hyperparams/<algo>.yml)")
    p.add_argument("--run-dir", default="runs/latest", help="folder for the model, statistics, curves and logs")
    p.add_argument("--overwrite", action="store_true", help="train into a run folder that already holds a model")
    p.add_argument("--seed", type=int_at_least(0), default=0)
    p.add_argument("--timesteps", type=int_at_least(1), help="override n_timesteps")
    p.add_argument("--n-envs", type=int_at_least(1, 256), help="override n_envs")
    p.add_argument("--eval-freq", type=int_at_least(1), help="env steps between evaluations")
    p.add_argument("--eval-episodes", type=int_at_least(1))
    p.add_argument("--resume", help="run folder or checkpoint .zip to continue from")
    p.add_argument("--max-minutes", type=positive_float, help="stop after this much wall time")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--no-tensorboard", action="store_true")
    p.set_defaults(func=cmd_train)

    policy_help = "shipped, pid, a run folder, a model .zip, a bundle folder or PID gains .json"
    p = sub.add_parser("evaluate", help=cmd_evaluate.__doc__, description=cmd_evaluate.__doc__)
    p.add_argument("--env", choices=ENV_CHOICES, help="default: the env the policy was trained for (balance for pid)")
    p.add_argument("--policy", default="shipped", help=policy_help)
    p.add_argument("--episodes", type=int_at_least(1), default=100)
    p.add_argument("--seed", type=int_at_least(0), default=0)
    p.add_argument("--no-randomize", action="store_true", help="nominal physics instead of domain randomisation")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--gif", help="write a GIF of one episode from the 100 mm offset")
    p.add_argument("--plot", help="write the ball path and pulse widths of that episode (PNG)")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("export", help=cmd_export.__doc__, description=cmd_export.__doc__)
    p.add_argument("--policy", default="shipped", help=policy_help)
    p.add_argument("--env", choices=ENV_CHOICES, help="which shipped policy (default balance)")
    p.add_argument("--out", required=True, help="bundle folder")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("deploy", help=cmd_deploy.__doc__, description=cmd_deploy.__doc__, epilog=EXIT_CODES_HELP)
    p.add_argument("--policy", default="shipped", help="a bundle folder, 'shipped' or 'pid'")
    p.add_argument("--env", choices=ENV_CHOICES, help="which shipped policy (default balance)")
    p.add_argument("--port", help="serial port (default: [hardware] port of the calibration file)")
    p.add_argument("--protocol", choices=PROTOCOL_CHOICES)
    p.add_argument("--baudrate", type=int_at_least(300, 4_000_000))
    p.add_argument("--sensor", choices=["sim", "panel"], default="sim")
    p.add_argument("--calibration", help="calibration TOML (trims, directions, limits, [hardware])")
    p.add_argument("--duration", type=positive_float, help="seconds (default: until Ctrl-C)")
    p.add_argument("--rate", type=bounded_float(0.0, 500.0, lo_open=True), default=50.0, help="control rate, Hz (≤ 500)")
    p.add_argument("--watchdog-ms", type=bounded_float(1.0, 10_000.0), default=100.0,
                   help="sensor data older than this sends the platform home")  # fmt: skip
    p.add_argument("--max-step-us", type=bounded_float(0.0, 1000.0, lo_open=True),
                   help="rate limit per channel per tick, µs (default 3000 µs/s ÷ rate: 60 at 50 Hz, just under "
                        "the reference servos' own speed)")  # fmt: skip
    p.add_argument("--trajectory", choices=["circle", "figure8", "waypoints"],
                   help="moving target of a track policy (default: the one it was trained on)")  # fmt: skip
    p.add_argument("--log", help="CSV log (default deploy_log_<date>-<time>.csv; never overwritten without --overwrite)")
    p.add_argument("--overwrite", action="store_true", help="allow --log to replace an existing file")
    p.add_argument("--seed", type=int_at_least(0), default=0, help="simulated plant's seed (--sensor sim)")
    p.add_argument("--no-randomize", action="store_true", help="nominal simulated plant")
    p.set_defaults(func=cmd_deploy)

    p = sub.add_parser("calibrate", help=cmd_calibrate.__doc__, description=cmd_calibrate.__doc__)
    p.add_argument("--port")
    p.add_argument("--protocol", choices=PROTOCOL_CHOICES)
    p.add_argument("--baudrate", type=int_at_least(300, 4_000_000))
    p.add_argument("--calibration", help="start from this calibration TOML")
    p.add_argument("--step", type=bounded_float(0.0, 100.0, lo_open=True), default=5.0, help="µs per key press")
    p.add_argument("--out", default="calibration.toml")
    p.set_defaults(func=cmd_calibrate)

    from stewart_gym.analysis.cli import register

    register(sub)
    p = sub.add_parser("demo", help=cmd_demo.__doc__, description=cmd_demo.__doc__)
    p.add_argument("--episodes", type=int_at_least(1), default=20)
    p.add_argument("--seed", type=int_at_least(0), default=0)
    p.add_argument("--out", default="out", help="folder for the GIF, plot and metrics")
    p.set_defaults(func=cmd_demo)
    for sp in sub.choices.values():  # --debug is accepted after the subcommand too
        sp.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show the traceback of any error")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run(args.func, args)


if __name__ == "__main__":
    sys.exit(main())
