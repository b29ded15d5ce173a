"""Plot learning curves (evaluation success rate and mean reward against wall time) of one or more runs.

Run: ``python train/tools/plot_learning_curve.py runs/ppo_balance runs/sac_balance --out docs/images/learning_curve.png``
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("runs", nargs="+", help="run folders with eval.csv")
    parser.add_argument("--out", required=True)
    parser.add_argument("--title", default="StewartBallBalance-v0, domain randomisation on, 2 CPU cores")
    args = parser.parse_args()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for run in args.runs:
        rows = list(csv.DictReader((Path(run) / "eval.csv").open()))
        minutes = [float(r["wall_s"]) / 60 for r in rows]
        label = Path(run).name
        ax1.plot(minutes, [100 * float(r["success_rate"]) for r in rows], marker="o", ms=3, label=label)
        ax2.plot([int(r["timesteps"]) / 1e3 for r in rows], [float(r["mean_reward"]) for r in rows], marker="o",
                 ms=3, label=label)
    ax1.axhline(95, color="0.5", ls="--", lw=1, label="95 %")
    ax1.set(xlabel="wall time [min]", ylabel="evaluation success [%]", ylim=(-5, 105))
    ax2.set(xlabel="environment steps [thousands]", ylabel="mean evaluation return")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(args.title)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(args.out)


if __name__ == "__main__":
    main()
