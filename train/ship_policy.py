"""Copy a trained run into the package as the shipped policy, with its ONNX bundle and metrics.

Run: ``python train/ship_policy.py runs/ppo_balance_ft [--model best] [--name balance] [--eval out/eval.json]``,
then add the folder to ``SHIPPED`` in ``stewart_gym/registry.py`` under its env id and geometry.
Writes ``stewart_gym/policies/<name>/``: model.zip, vecnormalize.pkl, config.yaml, eval.csv, metrics.json
(training metrics plus the 100-episode evaluation given by --eval) and bundle/ (policy.onnx, bundle.json).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from stewart_gym.registry import POLICY_DIR, export_policy, resolve_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("run", help="run folder")
    parser.add_argument("--model", choices=["final", "best"], default="final")
    parser.add_argument("--name", default="balance")
    parser.add_argument("--eval", help="JSON from `stewart-gym evaluate --json` to store with the policy")
    parser.add_argument("--note", default="", help="free text stored in metrics.json (e.g. how it was trained)")
    args = parser.parse_args()
    run = Path(args.run)
    src = run / "best" if args.model == "best" else run
    out = POLICY_DIR / args.name
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    shutil.copy(src / ("best_model.zip" if args.model == "best" else "model.zip"), out / "model.zip")
    shutil.copy(src / "vecnormalize.pkl", out / "vecnormalize.pkl")
    for name in ("config.yaml", "eval.csv"):
        shutil.copy(run / name, out / name)
    metrics = json.loads((run / "metrics.json").read_text())
    metrics["shipped_model"] = args.model
    metrics["note"] = args.note
    if args.eval:
        evaluation = json.loads(Path(args.eval).read_text().strip().splitlines()[-1])
        evaluation.pop("per_episode", None)  # the summary only: each seed's values belong to the results page
        metrics["evaluation_100_seeds"] = evaluation
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    export_policy(resolve_policy(str(out)), out / "bundle")  # env id, action mode and geometry from config.yaml
    print(f"shipped {src} as {out}")


if __name__ == "__main__":
    main()
