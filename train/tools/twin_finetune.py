"""Fine-tune the shipped policy for a fitted twin, and judge it on the true one.

Run: ``.venv/bin/python train/tools/twin_finetune.py [--twin slow-late] [--minutes 5] [--episodes 50]
[--folder runs/twin-finetune] [--retune-episodes 10]``, on a quiet machine (``identify`` runs in real time).

1. ``identify`` and ``sysid`` on the twin behind a virtual board (:func:`sysid_table.run_twin`);
2. ``stewart-gym train --resume shipped --twin FITTED --max-minutes M``;
3. the PID + Kalman retuned for the fitted twin (``train/tools/tune_pid.py --twin FITTED``, a small grid);
4. ``stewart-gym compare`` of the fine-tuned policy, the shipped one, the PID + Kalman, the retuned PID + Kalman
   and the LQR on ``--episodes`` of the *true* twin.

Writes the table into the results page and its intro, between :data:`MARKERS`, and ``compare.json`` into the
folder.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sysid_table import ROOT, SG, TWINS, run_twin, write_between  # noqa: E402

MARKERS = ("<!-- finetune table: train/tools/twin_finetune.py -->", "<!-- end finetune table -->")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--twin", default="slow-late", choices=sorted(TWINS))
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--retune-episodes", type=int, default=10)
    ap.add_argument("--folder", default="runs/twin-finetune")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    row = run_twin(args.twin, TWINS[args.twin], 60.0, folder, seed=list(TWINS).index(args.twin))
    true, fitted = folder / f"{args.twin}.toml", folder / f"{args.twin}-fitted.toml"
    run = folder / "run"
    subprocess.run([*SG, "train", "--resume", "shipped", "--twin", str(fitted), "--run-dir", str(run), "--overwrite",
                    "--max-minutes", str(args.minutes), "--seed", str(args.seed), "--no-progress"], check=True)
    metrics = json.loads((run / "metrics.json").read_text())
    gains = folder / "pid_kalman_twin.json"
    subprocess.run([sys.executable, str(ROOT / "train/tools/tune_pid.py"), "--twin", str(fitted), "--out", str(gains),
                    "--episodes", str(args.retune_episodes), "--kp-pos", "1.5,2,3", "--kp-vel", "3,4,5",
                    "--ki-vel", "2,3"], check=True)  # fmt: skip
    policies = [str(run), "shipped", "pid-kalman", str(gains), "lqr"]
    out = subprocess.run([*SG, "compare", *policies, "--twin", str(true), "--episodes", str(args.episodes), "--json"],
                         capture_output=True, text=True, check=True).stdout  # fmt: skip
    (folder / "compare.json").write_text(out)
    results = json.loads(out)["policies"]
    labels = {str(run): f"PPO fine-tuned for the fitted twin ({metrics['wall_time_s'] / 60:.1f} min)",
              "shipped": "shipped PPO", "pid-kalman": "PID + Kalman (shipped gains)",
              str(gains): "PID + Kalman retuned for the fitted twin", "lqr": "LQR"}  # fmt: skip
    shipped_rms = results["shipped"]["rms_error_mm"]
    lines = ["| controller | success | RMS error, last 5 s (mm) | × shipped's RMS | settling (s) | settled pulse rate "
             "(µs/s) |", "|---|---|---|---|---|---|"]
    for spec in policies:
        m = results[spec]
        settle = m.get("settling_time_s")
        lines.append(f"| {labels[spec]} | {m['success_rate']:.0%} | {m['rms_error_mm']:.2f} | "
                     f"{m['rms_error_mm'] / shipped_rms:.2f} | {'–' if settle is None else f'{settle:.2f}'} | "
                     f"{m['settled_pulse_rate_us_per_s']:.0f} |")  # fmt: skip
    table = "\n".join(lines) + (f"\n\nThe fit: total latency {row['latency_fit']:.1f} ms (true {row['latency_true']:.0f}),"
                                f" servo speed {row['speed_fit']:.2f} (true {row['speed_true']:.2f}), dead band "
                                f"{row['deadband_fit']:.1f} µs (true {row['deadband_true']:.0f}), panel noise "
                                f"{row['noise_fit']:.2f} mm (true {row['noise_true']:.1f}).")  # fmt: skip
    for page in (ROOT / "docs/src/results.md", ROOT / "train/tools/results_intro.md"):
        write_between(page, MARKERS, table)
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
