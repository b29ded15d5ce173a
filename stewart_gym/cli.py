"""The ``stewart-gym`` command line."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stewart_gym.analysis.cli import json_safe
from stewart_gym.geometry import load_geometry, preset_names
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.servo import ServoCalibration

if TYPE_CHECKING:
    from stewart_gym.sim import StewartSim


def _geometry_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--geometry", default="servo-hexapod", help=f"preset ({', '.join(preset_names())}) or TOML file")


def cmd_ik(args: argparse.Namespace) -> int:
    """Inverse kinematics of one pose: leg lengths, servo angles, pulse widths."""
    geo = load_geometry(args.geometry)
    pose = np.array([v * 1e-3 for v in args.pose[:3]] + [math.radians(v) for v in args.pose[3:]])
    ik = inverse_kinematics(geo, pose)
    out: dict = {
        "geometry": geo.name,
        "pose": {"x_mm": args.pose[0], "y_mm": args.pose[1], "z_mm": args.pose[2],
                 "roll_deg": args.pose[3], "pitch_deg": args.pose[4], "yaw_deg": args.pose[5]},  # fmt: skip
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
    return 0 if ik.reachable else 1


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: evaluate the shipped policy next to the PID baseline; write a GIF and a pulse-width plot."""
    from stewart_gym.evaluation import evaluate, format_table, load_policy

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env_id = "StewartBallBalance-v0"
    results = {}
    for name in ("shipped", "pid"):
        policy = load_policy(name, env_id)
        print(f"evaluating {name} on {args.episodes} seeded episodes with domain randomisation…", flush=True)
        results[name] = evaluate(env_id, policy, episodes=args.episodes, seed=args.seed)
    print()
    print(format_table(results))
    (out / "demo_metrics.json").write_text(json.dumps(json_safe(results), indent=2) + "\n")
    _episode_figures(env_id, load_policy("shipped", env_id), args.seed, True, str(out / "demo.gif"),
                     str(out / "demo_pulses.png"), "shipped")  # fmt: skip
    print(f"\nwrote {out / 'demo.gif'}, {out / 'demo_pulses.png'} and {out / 'demo_metrics.json'}")
    return 0


def cmd_urdf(args: argparse.Namespace) -> int:
    """Write the mechanism and plate URDFs of a rotary geometry."""
    from stewart_gym.sim.urdf import write_urdfs

    for path in write_urdfs(args.out, args.geometry):
        print(path)
    return 0


def settle_at(sim: StewartSim, pose: np.ndarray, seconds: float = 1.0) -> np.ndarray:
    """Command ``pose`` through IK → pulses, step ``seconds``, and return the pulses sent."""
    ik = inverse_kinematics(sim.geometry, pose)
    if not ik.reachable:
        raise ValueError(ik.explain())
    pulses = sim.calibration.pulse_widths(ik.servo_angles)
    sim.command(pulses)
    for _ in range(int(round(seconds * sim.control_hz))):
        sim.step()
    return pulses


def cmd_render(args: argparse.Namespace) -> int:
    """Render the simulated mechanism at a pose to a PNG file."""
    import imageio.v3 as iio

    from stewart_gym.sim import StewartSim

    pose = np.array([v * 1e-3 for v in args.pose[:3]] + [math.radians(v) for v in args.pose[3:]])
    size = (args.width, args.height)
    with StewartSim(args.geometry, ball=args.ball, render_mode="rgb_array", render_size=size) as sim:
        settle_at(sim, pose)
        if args.ball:
            sim.place_ball(np.zeros(2))
        iio.imwrite(args.out, sim.render())
        print(f"{args.out}: pose reached {np.round(sim.platform_pose()[:3] * 1e3, 3).tolist()} mm, "
              f"{np.round(np.degrees(sim.platform_pose()[3:]), 3).tolist()} deg")  # fmt: skip
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    """Train an agent with Stable-Baselines3 (PPO, SAC, TD3); hyperparameters from train/hyperparams/<algo>.yml."""
    from stewart_gym.training import TrainConfig, train

    cfg = TrainConfig(env_id=args.env, algo=args.algo, hyperparams=args.hyperparams, run_dir=args.run_dir,
                      seed=args.seed, n_timesteps=args.timesteps, n_envs=args.n_envs, eval_freq=args.eval_freq,
                      eval_episodes=args.eval_episodes, resume=args.resume, progress_bar=not args.no_progress,
                      tensorboard=not args.no_tensorboard)  # fmt: skip
    metrics = train(cfg, max_wall_s=args.max_minutes * 60 if args.max_minutes else None)
    print(json.dumps(metrics, indent=2))
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Evaluate a policy (shipped, pid or a path) on N seeded episodes; table or JSON."""
    from stewart_gym.evaluation import evaluate, format_table, load_policy

    policy = load_policy(args.policy, args.env)
    metrics = evaluate(args.env, policy, episodes=args.episodes, seed=args.seed, randomize=not args.no_randomize)
    if args.gif or args.plot:
        _episode_figures(args.env, policy, args.seed, not args.no_randomize, args.gif, args.plot, args.policy)
    if args.json:
        print(json.dumps(json_safe(metrics)))
    else:
        print(format_table({args.policy: metrics}))
    return 0


def _episode_figures(env_id: str, policy: object, seed: int, randomize: bool, gif: str | None, plot: str | None,
                     title: str) -> None:  # fmt: skip
    """Run one episode from the standard 100 mm offset; write its GIF and/or its ball-path and pulse-width plot."""
    import gymnasium as gym

    from stewart_gym.evaluation import SETTLING_OFFSET, plot_episode, run_episode, write_gif

    env = gym.make(env_id, randomize=randomize, render_mode="rgb_array" if gif else None)
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
    """Export a policy (shipped, pid, a run folder or model .zip) to a deployable ONNX/JSON bundle."""
    from stewart_gym.evaluation import POLICY_DIR
    from stewart_gym.hardware.export import export_pid, export_sb3

    if args.policy == "pid":
        out = export_pid(POLICY_DIR / "pid_gains.json", args.out, args.env)
    else:
        src = POLICY_DIR / "balance" if args.policy == "shipped" else Path(args.policy)
        out = export_sb3(src, args.out, args.env)
    print(f"bundle written to {out}")
    return 0


def _load_calibration(args: argparse.Namespace) -> tuple[ServoCalibration, dict]:
    from stewart_gym.servo import hardware_settings

    if args.calibration:
        return ServoCalibration.from_toml(args.calibration, "servo-hexapod"), hardware_settings(args.calibration)
    return ServoCalibration.default("servo-hexapod"), {}


def cmd_deploy(args: argparse.Namespace) -> int:
    """Run a policy on servos at a fixed rate (sensor → policy → IK → safety → serial)."""
    from stewart_gym.actions import ActionMapper
    from stewart_gym.evaluation import POLICY_DIR
    from stewart_gym.hardware.deploy import DeployConfig, DeployLoop, PanelSensor, SimulatedPlant
    from stewart_gym.hardware.devices import DeviceError, LineController, open_controller
    from stewart_gym.hardware.export import BundlePolicy, export_pid

    calibration, hw = _load_calibration(args)
    port = args.port or hw.get("port")
    protocol = args.protocol or hw.get("protocol", "maestro")
    if not port:
        print("error: no serial port (--port or [hardware] port in the calibration file)", file=sys.stderr)
        return 1
    if args.policy == "pid":
        import tempfile

        bundle = export_pid(POLICY_DIR / "pid_gains.json", Path(tempfile.mkdtemp(prefix="stewart_pid_")))
    elif args.policy == "shipped":
        bundle = POLICY_DIR / "balance" / "bundle"
    else:
        bundle = Path(args.policy)
    policy = BundlePolicy(bundle)
    try:
        controller = open_controller(protocol, port, calibration.channels, args.baudrate or hw.get("baudrate"))
    except DeviceError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.sensor == "panel":
        if not isinstance(controller, LineController):
            print("error: --sensor panel needs --protocol line (the Arduino reports the panel)", file=sys.stderr)
            controller.close()
            return 1
        sensor = PanelSensor(controller)
    else:
        sensor = SimulatedPlant(seed=args.seed, randomize=not args.no_randomize)
    mapper = ActionMapper("servo-hexapod", calibration, policy.action_mode)
    config = DeployConfig(rate_hz=args.rate, duration_s=args.duration, watchdog_s=args.watchdog_ms / 1000,
                          max_step_us=args.max_step_us, log_path=args.log)  # fmt: skip
    loop = DeployLoop(policy, mapper, controller, sensor, config)
    summary = loop.run()
    if isinstance(sensor, SimulatedPlant):
        summary.message += f"; simulated ball {sensor.ball_error_mm():.1f} mm from the centre"
    print(summary.text())
    print(f"log: {args.log}")
    return summary.exit_code


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Find servo trims: step one servo at a time; keys on stdin: + / - (trim), n (next servo), q (save and quit)."""
    from stewart_gym.hardware.devices import open_controller

    calibration, hw = _load_calibration(args)
    port, protocol = args.port or hw.get("port"), args.protocol or hw.get("protocol", "maestro")
    if not port:
        print("error: no serial port (--port or [hardware] port in the calibration file)", file=sys.stderr)
        return 1
    controller = open_controller(protocol, port, calibration.channels, args.baudrate or hw.get("baudrate"))
    trims = calibration.neutral_us - 1500.0
    servo = 0
    try:
        print("servo 0: + / - move by", args.step, "µs, n = next servo, q = save and quit", flush=True)
        controller.send(np.clip(1500.0 + trims, calibration.min_us, calibration.max_us))
        for line in sys.stdin:
            key = line.strip()
            if key in ("+", "-"):
                trims[servo] += args.step if key == "+" else -args.step
            elif key == "n":
                servo = (servo + 1) % 6
            elif key == "q":
                break
            pulses = np.clip(1500.0 + trims, calibration.min_us, calibration.max_us)
            controller.send(pulses)
            print(f"servo {servo}: trims {np.round(trims, 1).tolist()} µs", flush=True)
    finally:
        controller.send(calibration.neutral_us)
        controller.close()
    shift = trims - (calibration.neutral_us - 1500.0)  # the channel limits move with the neutral pulse
    cal = ServoCalibration(1500.0 + trims, calibration.direction, calibration.home_angle, calibration.us_per_rad,
                           calibration.min_us + shift, calibration.max_us + shift, calibration.channels)
    text = cal.to_toml()
    if hw:
        text += "\n[hardware]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in hw.items())
    Path(args.out).write_text(text)
    print(f"calibration written to {args.out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="stewart-gym", description="Servo Stewart platform toolkit")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("ik", help=cmd_ik.__doc__)
    _geometry_arg(p)
    p.add_argument("pose", nargs=6, type=float, metavar=("X_MM", "Y_MM", "Z_MM", "ROLL_DEG", "PITCH_DEG", "YAW_DEG"))
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_ik)
    p = sub.add_parser("urdf", help=cmd_urdf.__doc__)
    _geometry_arg(p)
    p.add_argument("--out", default="urdf", help="directory (default urdf/)")
    p.set_defaults(func=cmd_urdf)
    p = sub.add_parser("render", help=cmd_render.__doc__)
    _geometry_arg(p)
    p.add_argument("pose", nargs=6, type=float, metavar=("X_MM", "Y_MM", "Z_MM", "ROLL_DEG", "PITCH_DEG", "YAW_DEG"))
    p.add_argument("--out", required=True, help="PNG file")
    p.add_argument("--ball", action="store_true", help="put a ball on the plate")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.set_defaults(func=cmd_render)
    p = sub.add_parser("train", help=cmd_train.__doc__)
    p.add_argument("--env", default="StewartBallBalance-v0")
    p.add_argument("--algo", choices=["ppo", "sac", "td3"], default="ppo")
    p.add_argument("--hyperparams", help="YAML file (default train/hyperparams/<algo>.yml)")
    p.add_argument("--run-dir", default="runs/latest")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--timesteps", type=int, help="override n_timesteps")
    p.add_argument("--n-envs", type=int, help="override n_envs")
    p.add_argument("--eval-freq", type=int, help="env steps between evaluations")
    p.add_argument("--eval-episodes", type=int)
    p.add_argument("--resume", help="run folder or checkpoint .zip to continue from")
    p.add_argument("--max-minutes", type=float, help="stop after this much wall time")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--no-tensorboard", action="store_true")
    p.set_defaults(func=cmd_train)
    p = sub.add_parser("evaluate", help=cmd_evaluate.__doc__)
    p.add_argument("--env", default="StewartBallBalance-v0")
    p.add_argument("--policy", default="shipped", help="shipped, pid, a run folder, a model .zip or PID gains .json")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-randomize", action="store_true", help="nominal physics instead of domain randomisation")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--gif", help="write a GIF of one episode from the 100 mm offset")
    p.add_argument("--plot", help="write the ball path and pulse widths of that episode (PNG)")
    p.set_defaults(func=cmd_evaluate)
    p = sub.add_parser("export", help=cmd_export.__doc__)
    p.add_argument("--policy", default="shipped")
    p.add_argument("--env", default="StewartBallBalance-v0")
    p.add_argument("--out", required=True, help="bundle folder")
    p.set_defaults(func=cmd_export)
    p = sub.add_parser("deploy", help=cmd_deploy.__doc__)
    p.add_argument("--policy", default="shipped", help="a bundle folder, 'shipped' or 'pid'")
    p.add_argument("--port", help="serial port (default: [hardware] port of the calibration file)")
    p.add_argument("--protocol", choices=["maestro", "ssc32", "line"])
    p.add_argument("--baudrate", type=int)
    p.add_argument("--sensor", choices=["sim", "panel"], default="sim")
    p.add_argument("--calibration", help="calibration TOML (trims, directions, limits, [hardware])")
    p.add_argument("--duration", type=float, help="seconds (default: until Ctrl-C)")
    p.add_argument("--rate", type=float, default=50.0, help="control rate, Hz")
    p.add_argument("--watchdog-ms", type=float, default=100.0)
    p.add_argument("--max-step-us", type=float, default=40.0, help="rate limit per channel per tick")
    p.add_argument("--log", default="deploy_log.csv")
    p.add_argument("--seed", type=int, default=0, help="simulated plant's seed (--sensor sim)")
    p.add_argument("--no-randomize", action="store_true", help="nominal simulated plant")
    p.set_defaults(func=cmd_deploy)
    p = sub.add_parser("calibrate", help=cmd_calibrate.__doc__)
    p.add_argument("--port")
    p.add_argument("--protocol", choices=["maestro", "ssc32", "line"])
    p.add_argument("--baudrate", type=int)
    p.add_argument("--calibration", help="start from this calibration TOML")
    p.add_argument("--step", type=float, default=5.0, help="µs per key press")
    p.add_argument("--out", default="calibration.toml")
    p.set_defaults(func=cmd_calibrate)
    from stewart_gym.analysis.cli import register

    register(sub)
    p = sub.add_parser("demo", help=cmd_demo.__doc__)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="out", help="folder for the GIF, plot and metrics")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
