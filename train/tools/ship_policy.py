"""Copy a trained run, or an ensemble folder, into the package as a shipped policy, with its ONNX bundle and metrics.

Run: ``python train/tools/ship_policy.py runs/ppo_balance_ft [--model best] [--name balance] [--eval out/eval.json]``,
then add the folder to ``SHIPPED`` in ``stewart_gym/registry.py`` under its env id and geometry.
Writes ``stewart_gym/policies/<name>/``: model.zip, vecnormalize.pkl, config.yaml, eval.csv, metrics.json
(training metrics plus the 100-episode evaluation given by --eval) and bundle/ (policy.onnx, bundle.json).
An ensemble folder (``stewart-gym ensemble``) is copied whole (ensemble.json, members/, each member's run files);
its metrics.json holds the members' training metrics and the evaluation.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from stewart_gym.outputs import ENSEMBLE_FILE, ensemble_members
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
    evaluation = read_evaluation(Path(args.eval)) if args.eval else None  # before the shipped folder is replaced
    ensemble = (run / ENSEMBLE_FILE).is_file()
    missing = [] if ensemble else [p for p in run_files(run, src, args.model).values() if not p.is_file()]
    if missing:  # checked before the shipped folder is replaced
        raise SystemExit(f"error: {run}: no {', '.join(p.name for p in missing)} (nor {ENSEMBLE_FILE}); give a "
                         "finished run folder (stewart-gym train) or an ensemble folder (stewart-gym ensemble)")  # fmt: skip
    if out.exists():
        shutil.rmtree(out)
    if ensemble:
        top = run.resolve()  # its own bundle and metrics are written below; the members' files are kept
        shutil.copytree(run, out, ignore=lambda d, names: [n for n in names if Path(d).resolve() == top
                                                           and n in ("bundle", "metrics.json")])  # fmt: skip
        members = ensemble_members(run)
        metrics = {"ensemble": len(members), "members": [json.loads((m / "metrics.json").read_text()) for m in members]}
    else:
        metrics = ship_run(run, src, out, args.model)
    metrics["note"] = args.note
    if evaluation is not None:
        metrics["evaluation_100_seeds"] = evaluation
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    export_policy(resolve_policy(str(out)), out / "bundle", overwrite=True)  # env id, action mode, geometry: config.yaml
    print(f"shipped {src} as {out}")


def read_evaluation(path: Path) -> dict:
    """The evaluation summary in ``path``: ``evaluate --json``'s object, the file's last line (after any log lines)
    or the whole file (indented); each seed's values are left out (they belong to the results page)."""
    try:
        text = path.read_text().strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise SystemExit(f"error: --eval {path}: cannot read it ({exc.__class__.__name__})") from None
    try:
        evaluation = json.loads(text)
    except json.JSONDecodeError:
        try:
            evaluation = json.loads(text.splitlines()[-1] if text else "")
        except json.JSONDecodeError:
            raise SystemExit(f"error: --eval {path}: no JSON object in it (write it with `stewart-gym evaluate "
                             "--json > FILE`)") from None  # fmt: skip
    if not isinstance(evaluation, dict):
        raise SystemExit(f"error: --eval {path}: expected a JSON object, got {type(evaluation).__name__}")
    evaluation.pop("per_episode", None)
    return evaluation


def run_files(run: Path, src: Path, model: str) -> dict[str, Path]:
    """What :func:`ship_run` takes from a run, by the name it ships under: the model (``final`` or ``best``, in
    ``src``), its statistics, the configuration, the learning curve and the training metrics."""
    return {"model.zip": src / ("best_model.zip" if model == "best" else "model.zip"),
            "vecnormalize.pkl": src / "vecnormalize.pkl", "config.yaml": run / "config.yaml",
            "eval.csv": run / "eval.csv", "metrics.json": run / "metrics.json"}  # fmt: skip


def ship_run(run: Path, src: Path, out: Path, model: str) -> dict:
    """Copy one run's files (:func:`run_files`) into ``out``; its training metrics."""
    out.mkdir(parents=True)
    files = run_files(run, src, model)
    for name, path in files.items():
        if name != "metrics.json":
            shutil.copy(path, out / name)
    metrics = json.loads(files["metrics.json"].read_text())
    metrics["shipped_model"] = model
    return metrics


if __name__ == "__main__":
    main()
