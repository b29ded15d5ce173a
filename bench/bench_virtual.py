"""Virtual hardware end to end: ``deploy`` against ``stewart-gym virtual-device`` (the twin behind a pty), in real time.

Run: ``.venv/bin/python bench/bench_virtual.py [--runs 10] [--seconds 15] [--backend mujoco] [--protocol line]``.

Each run starts a board (``--seed k``: the ball's random start, the episode's physics and panel noise), deploys
the shipped balance policy on it (``--sensor panel`` over the line protocol: the ball is read from the wire, as
from the Arduino sketch; ``--sensor sim`` for Maestro and SSC-32), stops the board with SIGINT and reads both
summaries. Prints, per run and overall: falls, the ball's final distance from the centre (the twin's truth with
the panel; with ``--sensor sim``, the deploy's own simulated ball, since the twin's ball then goes unobserved),
the RMS distance over the last 5 s as the controller saw it (panel noise included), and the deploy's missed
deadlines.
"""

from __future__ import annotations

import argparse
import csv
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SG = [sys.executable, "-m", "stewart_gym"]


def one_run(seed: int, seconds: float, backend: str, protocol: str, folder: Path) -> dict:
    link, log = folder / f"board{seed}", folder / f"deploy{seed}.csv"
    board = subprocess.Popen([*SG, "virtual-device", "--protocol", protocol, "--backend", backend, "--seed", str(seed),
                              "--link", str(link)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    while not link.is_symlink():
        if board.poll() is not None:
            raise RuntimeError(board.communicate()[1])
        time.sleep(0.05)
    sensor = "panel" if protocol == "line" else "sim"
    seeded = ["--seed", str(seed)] if sensor == "sim" else []  # (a seed is the simulated plant's: --sensor sim)
    dep = subprocess.run([*SG, "deploy", "--policy", "shipped", "--protocol", protocol, "--sensor", sensor, "--port",
                          str(link), "--duration", str(seconds), "--log", str(log), "--overwrite", *seeded],
                         capture_output=True, text=True)  # fmt: skip
    board.send_signal(signal.SIGINT)
    out, _ = board.communicate(timeout=60)
    if not log.exists():  # deploy refused to start: its own line says why
        lines = (dep.stderr or dep.stdout).strip().splitlines()
        raise SystemExit(f"error: deploy exited {dep.returncode} before its first tick: {lines[-1] if lines else ''}")
    rows = list(csv.DictReader(log.open()))
    t = np.array([float(r["t_s"]) for r in rows])
    xy = np.array([[float(r["obs0"]), float(r["obs1"])] for r in rows]) * 150.0  # obs × half plate (mm)
    tail = t > t[-1] - 5.0
    summary = out.strip().splitlines()[-1]
    if sensor == "panel":  # the host balanced the twin's ball: the board's summary has the truth
        distance = float(summary.split(" mm from the centre")[0].rsplit(", ", 1)[1])
        fell = "fell off" in summary
    else:  # the host balanced its own simulated ball; the twin's ball went unobserved (open loop)
        distance = float(dep.stdout.split("simulated ball ")[1].split(" mm")[0])
        fell = distance > 150.0
    return {"seed": seed, "deploy_exit": dep.returncode, "fell_off": fell, "final_distance_mm": distance,
            "panel_rms_last_5s_mm": float(np.sqrt(np.mean(np.sum(xy[tail] ** 2, 1)))),
            "missed_deadlines": int(dep.stdout.split("missed deadlines ")[1].split(",")[0]),
            "malformed": int(summary.split(" malformed")[0].rsplit(", ", 1)[1])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--backend", choices=["pybullet", "mujoco"], default="mujoco")
    parser.add_argument("--protocol", choices=["line", "maestro", "ssc32"], default="line")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.runs < 1 or not args.seconds >= 6.0:
        parser.error("--runs must be 1 or more and --seconds at least 6 (the summary reads the last 5 s)")
    with tempfile.TemporaryDirectory() as tmp:
        runs = [one_run(k, args.seconds, args.backend, args.protocol, Path(tmp)) for k in range(args.runs)]
    res = {"backend": args.backend, "protocol": args.protocol, "seconds": args.seconds, "runs": runs,
           "falls": sum(r["fell_off"] for r in runs), "deploy_failures": sum(r["deploy_exit"] != 0 for r in runs),
           "malformed": sum(r["malformed"] for r in runs),
           "final_distance_mm_mean": float(np.mean([r["final_distance_mm"] for r in runs])),
           "panel_rms_last_5s_mm": float(np.sqrt(np.mean([r["panel_rms_last_5s_mm"] ** 2 for r in runs])))}
    if args.json:
        print(json.dumps(res))
        return
    for r in runs:
        print(f"  seed {r['seed']}: exit {r['deploy_exit']}, {'FELL OFF' if r['fell_off'] else 'on the plate'}, final "
              f"{r['final_distance_mm']:.1f} mm from the centre, RMS seen (last 5 s) {r['panel_rms_last_5s_mm']:.1f} mm, "
              f"{r['missed_deadlines']} missed deadlines")  # fmt: skip
    print(f"{args.runs} runs of {args.seconds:g} s, {args.protocol} protocol, twin in {args.backend}: {res['falls']} falls, "
          f"{res['deploy_failures']} failed deploys, {res['malformed']} malformed messages, "
          f"final distance {res['final_distance_mm_mean']:.1f} mm on average, "
          f"RMS seen over the last 5 s {res['panel_rms_last_5s_mm']:.1f} mm")  # fmt: skip


if __name__ == "__main__":
    main()
