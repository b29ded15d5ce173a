"""``stewart-gym`` commands of the reality gap: identify (the excitation experiment) and sysid (fit a twin)."""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path
from typing import Any

from stewart_gym.cli.common import (
    EXIT_CODES_HELP,
    EXIT_OK,
    MAX_SEED,
    add_backend,
    add_geometry,
    add_twin,
    bounded_float,
    int_at_least,
    json_safe,
    output_dir,
    output_file,
    twin_tables,
)
from stewart_gym.cli.hardware import add_port
from stewart_gym.errors import ConfigError
from stewart_gym.outputs import no_folders_named

__all__ = ["register"]


def cmd_identify(args: argparse.Namespace) -> int:
    """Run the excitation experiment that stewart-gym sysid fits a twin from: the PID + Kalman keeps the ball on
    the plate while pseudo-random tilt steps make it roll (with a camera, the plate also moves in height and yaw
    and in large tilt triplets, and the log holds the plate pose the camera sees, for each servo's trim). It is a
    deploy run: the same checks before the port opens, the same safety layer and channel limits, the servos home
    on every stop; it writes the deploy log."""
    from stewart_gym.hardware.deploy_setup import DeployOptions, DeploySetup
    from stewart_gym.hardware.identify import IDENTIFY_MAX_STEP_US_PER_S, Excitation
    from stewart_gym.registry import deployable_policy, resolve_policy

    base = deployable_policy(resolve_policy("pid-kalman", "StewartBallBalance-v0", args.geometry))
    policy = Excitation(base, rate_hz=args.rate, amplitude=args.amplitude, seed=args.seed)
    options = DeployOptions(port=args.port, protocol=args.protocol, baudrate=args.baudrate, sensor=args.sensor,
                            camera_config=args.camera_config, calibration=args.calibration, backend=args.backend,
                            rate_hz=args.rate, duration_s=args.duration, watchdog_s=args.watchdog_ms / 1000,
                            max_step_us=args.max_step_us or IDENTIFY_MAX_STEP_US_PER_S / args.rate, log=args.out,
                            overwrite=args.overwrite, seed=args.seed, randomize=False,
                            answer_timeout_s=args.answer_timeout_ms / 1000, twin=twin_tables(args.twin))  # fmt: skip
    setup = DeploySetup(policy, options, say=lambda line: print(line, flush=True))
    moves = ""
    if args.sensor == "camera":  # the camera sees the plate: height and yaw moves show each servo's trim
        policy.move_plate(setup.mapper)
        moves = (f", with height and yaw moves of the plate and tilt triplets (up to {policy.max_tilt_action:g} of "
                 "the tilt range) for the camera")  # fmt: skip
    print(f"identify: {args.duration:g} s of tilt steps (±{args.amplitude:g} of the tilt range){moves} under the "
          f"PID + Kalman; Ctrl-C stops it and homes the servos", flush=True)  # fmt: skip
    summary = setup.run()
    print(summary.text(), flush=True)
    from stewart_gym.sysid import unfit_reason

    width, depth = setup.mapper.geometry.plate_extent
    why = unfit_reason(setup.log, (width / 2, depth / 2)) if Path(setup.log).is_file() else "no log was written"
    if why is None:
        markers = " --marker-height-mm H (your markers' thickness)" if args.sensor == "camera" else ""
        print(f"log: {setup.log} (fit a twin from it: stewart-gym sysid {setup.log}{markers} --out twin.toml)",
              flush=True)  # fmt: skip
    else:
        print(f"log: {setup.log} (too short to fit a twin from alone: {why.removeprefix(f'{setup.log}: ')})",
              flush=True)  # fmt: skip
    return summary.exit_code


def cmd_sysid(args: argparse.Namespace) -> int:
    """Fit a platform's twin from its logs (identify's, or any deploy log): the total latency, the servos' speed
    and dead band, the plate's tilt offset and the readings' noise, and from a camera's log each servo's trim, each
    with its uncertainty; it says what the logs could not determine, and how much better the fitted twin
    predicts the ball on a held-out part of the logs."""
    from stewart_gym.calibration import ServoCalibration
    from stewart_gym.hardware.deploy_setup import load_calibration
    from stewart_gym.presets import load_geometry
    from stewart_gym.progress import Progress
    from stewart_gym.sim.twin import load_twin
    from stewart_gym.sysid import REPORT_FILES, fit_twin, read_log, write_report

    out = output_file(args.out, suffixes=(".toml",), overwrite=args.overwrite)
    report = None if args.report is None else output_dir(args.report)
    if report is not None and (report / "report.md").exists() and not args.overwrite:
        raise ConfigError(f"{report} holds a report already; give another folder or --overwrite")
    if report is not None and report.resolve() == out.resolve():
        raise ConfigError(f"--out and --report both name {out}: give the twin file and the report folder two names")
    if report is not None:
        no_folders_named(report, REPORT_FILES, "the report", "--report folder")
    twice = sorted({p for p in args.logs if sum(Path(q).resolve() == Path(p).resolve() for q in args.logs) > 1})
    if twice:
        raise ConfigError(f"{', '.join(twice)}: a log given twice would count its windows twice; give each once")
    geometry = load_geometry(args.geometry)
    calibration: ServoCalibration
    calibration, _ = load_calibration(args.calibration, geometry, used_for=f"--geometry {args.geometry}")
    start = load_twin(args.start) if args.start else None
    width, depth = geometry.plate_extent
    logs = [read_log(path, (width / 2, depth / 2)) for path in args.logs]
    progress = Progress(100, "%", "sysid")
    result = fit_twin(logs, geometry, calibration, start=start, holdout=args.holdout,
                      on_progress=lambda f: progress.advance(100 * f - progress.done),
                      marker_height=args.marker_height_mm / 1e3)  # fmt: skip
    progress.close()
    twin = result.twin
    out.parent.mkdir(parents=True, exist_ok=True)  # (output_file checked that it can be made)
    text = f"# fitted by stewart-gym sysid from {', '.join(args.logs)}\n" + twin.toml(
        {name: "undetermined" for name in twin.undetermined})
    # the report and the twin are written aside and put in place at the end, the twin last: a run stopped while
    # they are written leaves no half report and no twin, and its rerun is not refused for them
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=".sysid-") as scratch:
        draft = Path(scratch) / out.name
        draft.write_text(text, encoding="utf-8")
        if report is not None:
            report.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=report, prefix=".sysid-") as pages:
                for page in write_report(result, pages, args.logs):
                    os.replace(page, report / page.name)
        os.replace(draft, out)
    if args.json:
        print(json.dumps(json_safe({"twin": twin.to_mapping(), "total_latency_ms": result.total_latency_ms,
                                    "noise_mm": result.noise_mm, "sensor": result.sensor,
                                    "prediction": {str(h): v for h, v in result.prediction.items()},
                                    "trim_sigma_us": None if result.trim_fit is None else
                                    result.trim_fit.sigma_us.tolist(), "out": str(out)})))  # fmt: skip
    else:
        print("\n".join(result.lines()))
        print(f"twin written to {out}" + (f"; report in {report}" if report is not None else ""))
    return EXIT_OK


def register(sub: Any) -> None:
    """Add identify and sysid to the ``stewart-gym`` parser."""
    p = sub.add_parser("identify", help=cmd_identify.__doc__.split(":")[0] + ".", description=cmd_identify.__doc__,
                       epilog=EXIT_CODES_HELP)  # fmt: skip
    add_geometry(p)
    add_port(p)
    p.add_argument("--sensor", choices=["panel", "camera", "sim"], default="panel",
                   help="where the ball position comes from: the board's touch panel (default), a camera, or the "
                        "simulated plant (a dry run)")  # fmt: skip
    p.add_argument("--camera-config", help="camera config TOML (--sensor camera)")
    add_backend(p, "physics engine of the simulated plant (--sensor sim)")
    add_twin(p, "the simulated plant's twin (--sensor sim)")
    p.add_argument("--calibration", help="calibration TOML (trims, directions, limits, [hardware])")
    p.add_argument("--duration", type=bounded_float(5.0, 3600.0), default=60.0, help="seconds, 5 to 3600 (default 60)")
    p.add_argument("--out", required=True, help="the log to write (CSV, the deploy log's columns)")
    p.add_argument("--overwrite", action="store_true", help="allow --out to replace an existing file")
    p.add_argument("--amplitude", type=bounded_float(0.0, 0.6, lo_open=True), default=0.3,
                   help="largest tilt step, as a fraction of the controller's tilt range (default 0.3)")
    p.add_argument("--rate", type=bounded_float(10.0, 500.0), default=50.0, help="control rate, Hz (default 50)")
    p.add_argument("--max-step-us", type=bounded_float(0.0, 1000.0, lo_open=True),
                   help="rate limit per channel per tick, µs (default 10000 µs/s ÷ rate: 200 at 50 Hz, so that the "
                        "log shows the servos' own speed)")  # fmt: skip
    p.add_argument("--watchdog-ms", type=bounded_float(1.0, 10_000.0), default=100.0,
                   help="sensor data older than this sends the platform home")  # fmt: skip
    p.add_argument("--answer-timeout-ms", type=bounded_float(50.0, 60_000.0), default=500.0,
                   help="a board that leaves a position query unanswered this long has failed (default 500)")
    p.add_argument("--seed", type=int_at_least(0, MAX_SEED), default=0,
                   help="the excitation sequence's seed (and the simulated plant's, --sensor sim)")  # fmt: skip
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("sysid", help=cmd_sysid.__doc__.split(":")[0] + ".", description=cmd_sysid.__doc__)
    p.add_argument("logs", nargs="+", metavar="LOG", help="deploy logs (CSV) of one platform, at one rate")
    add_geometry(p)
    p.add_argument("--calibration", help="calibration TOML the logs were run with (default: the geometry's)")
    p.add_argument("--out", required=True, help="the twin to write (TOML)")
    p.add_argument("--overwrite", action="store_true",
                   help="allow --out and --report to replace an existing twin and report")  # fmt: skip
    p.add_argument("--report", metavar="DIR", help="write report.md and paths.png (logged against predicted ball "
                                                   "paths, nominal and fitted twin) into this folder")
    p.add_argument("--start", metavar="TWIN", help="the twin whose undetermined values the fit keeps (default: "
                                                   "nominal)")
    p.add_argument("--holdout", type=bounded_float(0.0, 0.8), default=0.3,
                   help="fraction of each log kept out of the fit to judge its predictions (default 0.3)")
    # 20: stewart_gym.sysid.MAX_MARKER_HEIGHT, which the parser cannot import (sysid needs pyserial, which a
    # demo-only install lacks); tests/test_sysid.py keeps the two equal
    p.add_argument("--marker-height-mm", type=bounded_float(0.0, 20.0), default=0.0,
                   help="camera logs: how far the markers' faces lie above the plate's top, mm (their thickness: "
                        "about 0.1 printed on paper, 3 cut from acrylic; default 0)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_sysid)
