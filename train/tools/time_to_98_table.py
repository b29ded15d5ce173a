"""Put the training-time figures of ``bench/bench_time_to_98.py`` on the results page.

Run: ``.venv/bin/python bench/bench_time_to_98.py --recipes ppo_batched --eval-freq 12500 --json > b.json``
(and ``--budget-s 30 --json``, ``--recipes ppo``, ``--env track`` …), then
``.venv/bin/python train/tools/time_to_98_table.py b.json [MORE.json …]``.

Each file is one run of the bench (``--json``). Its runs replace those of the same task, recipe and kind (time to
≥ 98 %, or a fixed budget) in ``docs/src/time_to_98.json``; the others are kept. The tables made of that file go
into the results page and its intro (``train/tools/results_intro.md``) between :data:`MARKERS`, and the balance
recipes' range into the README between :data:`README_MARKERS`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sysid_table import ROOT, write_between  # noqa: E402

MARKERS = ("<!-- time-to-98 table: train/tools/time_to_98_table.py -->", "<!-- end time-to-98 table -->")
#: Where the README's sentence on the balance recipes' time to ≥ 98 % goes (:func:`readme_sentence`).
README_MARKERS = ("<!-- time-to-98 sentence: train/tools/time_to_98_table.py -->", "<!-- end time-to-98 sentence -->")
SAVED = ROOT / "docs/src/time_to_98.json"
TASKS = {"balance": "balance", "track": "track (mixed)"}


def runs_of(benches: list[dict]) -> list[dict]:
    """Every run of the bench outputs, each with its bench's task, episodes and kind (``budget_s`` None: time
    to ≥ 98 %)."""
    return [{**run, "env": b["env"], "episodes": b["episodes"], "eval_freq": b.get("eval_freq"),
             "budget_s": b.get("budget_s")} for b in benches for run in b["runs"]]  # fmt: skip


def merged(saved: list[dict], fresh: list[dict]) -> list[dict]:
    """``saved`` runs with those of ``fresh``'s task, recipe and kind replaced by ``fresh``'s."""
    def key(run: dict) -> tuple:
        return run["env"], run["recipe"], run["budget_s"] is None

    replaced = {key(r) for r in fresh}
    return [r for r in saved if key(r) not in replaced] + fresh


def _engines(run: dict) -> str:
    return " / ".join(f"{run[b]:.0%}" if b in run else "–" for b in ("pybullet", "mujoco"))


def time_table(runs: list[dict]) -> str:
    """Time to the first checkpoint holding ≥ 98 % of the held-out episodes in PyBullet and in MuJoCo."""
    out = ["| task | recipe | seed | a checkpoint every (steps) | steps | training wall time (s) "
           "| its in-training evaluation back at (s) | held-out success, PyBullet / MuJoCo |",
           "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in (r for r in runs if r["budget_s"] is None):
        if r["wall_s"] is None:
            tried = r["candidates"][-1] if r["candidates"] else None
            best = f"best tried: {_engines(tried)} at {tried['timesteps']:,} steps" if tried else "no candidate"
            out.append(f"| {TASKS[r['env']]} | `{r['recipe']}` | {r['seed']} | {r['eval_freq']:,} "
                       f"| none in {r['trained_s']:.0f} s | – | – | {best} |")  # fmt: skip
            continue
        out.append(f"| {TASKS[r['env']]} | `{r['recipe']}` | {r['seed']} | {r['eval_freq']:,} | {r['timesteps']:,} "
                   f"| {r['wall_s']:.1f} | {r['evaluated_s']:.1f} | {_engines(r)} |")  # fmt: skip
    return "\n".join(out)


def budget_table(runs: list[dict]) -> str:
    """Runs stopped at a fixed wall time: the final model's held-out success and RMS error in each engine."""
    out = ["| task | recipe | seed | budget (s) | steps | PyBullet: success (RMS mm) | MuJoCo: success (RMS mm) |",
           "|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in (r for r in runs if r["budget_s"] is not None):
        cells = " | ".join(f"{r[b]:.0%} ({r[f'{b}_rms_mm']:.2f})" for b in ("pybullet", "mujoco"))
        out.append(f"| {TASKS[r['env']]} | `{r['recipe']}` | {r['seed']} | {r['budget_s']:g} | {r['timesteps']:,} "
                   f"| {cells} |")  # fmt: skip
    return "\n".join(out)


def readme_sentence(runs: list[dict]) -> str:
    """The README's sentence: the range of the batched and the PyBullet balance recipes' times to ≥ 98 %, over
    their training seeds (saying how many seeds got there where some did not)."""
    def span(recipe: str) -> str:
        tried = [r for r in runs if r["env"] == "balance" and r["recipe"] == recipe and r["budget_s"] is None]
        times = [r["wall_s"] for r in tried if r["wall_s"] is not None]
        if not times:
            raise ValueError(f"no balance run of {recipe} reached ≥ 98 %: the README sentence needs one")
        low, high = f"{min(times):.0f}", f"{max(times):.0f}"
        text = f"{low} s" if low == high else f"{low}–{high} s"
        return text if len(times) == len(tried) else f"{text} ({len(times)} of {len(tried)} training seeds)"

    return (f"From scratch, `ppo_batched` holds ≥ 98 % of held-out balance episodes in PyBullet and in MuJoCo after "
            f"{span('ppo_batched')} of training on 2 cores, against {span('ppo')} for the PyBullet recipe "
            "([training time](docs/src/results.md#training-time), with runs stopped at a fixed budget).")


def tables(runs: list[dict]) -> str:
    """Both tables, each where it has runs, with the held-out episodes they were judged on; rows by task (as
    :data:`TASKS`), recipe and seed, a seed run twice in the order of its runs."""
    order = list(TASKS)
    runs = sorted(runs, key=lambda r: (order.index(r["env"]), r["recipe"], r["seed"]))
    parts = []
    timed = [r for r in runs if r["budget_s"] is None]
    if timed:
        parts.append(f"Time to ≥ 98 % (held-out: {timed[0]['episodes']} randomised episodes per engine):\n\n"
                     f"{time_table(runs)}")  # fmt: skip
    if len(timed) < len(runs):
        budgeted = [r for r in runs if r["budget_s"] is not None]
        parts.append(f"A fixed budget (held-out: {budgeted[0]['episodes']} randomised episodes per engine):\n\n"
                     f"{budget_table(runs)}")  # fmt: skip
    return "\n\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bench", nargs="+", help="outputs of bench/bench_time_to_98.py --json")
    ap.add_argument("--page", action="append",
                    help="page to write the tables into, between the markers (default: the results page and its "
                         "intro, train/tools/results_intro.md)")  # fmt: skip
    args = ap.parse_args(argv)
    benches = []
    for name in args.bench:
        try:
            bench = json.loads(Path(name).read_text())
        except (OSError, ValueError) as exc:
            ap.error(f"{name}: not a bench_time_to_98.py --json output ({exc})")
        runs = bench.get("runs") if isinstance(bench, dict) else None
        if not (isinstance(runs, list) and bench.get("env") in TASKS and {"budget_s", "episodes"} <= set(bench)
                and all(isinstance(r, dict) and {"recipe", "seed", "timesteps"} <= set(r) for r in runs)):
            ap.error(f"{name}: not a bench_time_to_98.py --json output (it needs env, episodes, budget_s and runs, "
                     "each with its recipe, seed and steps)")  # fmt: skip
        benches.append(bench)
    saved = json.loads(SAVED.read_text()) if SAVED.is_file() else []
    runs = merged(saved, runs_of(benches))
    made = tables(runs)
    try:
        sentence = None if args.page else readme_sentence(runs)
    except ValueError as exc:
        ap.error(str(exc))
    SAVED.write_text(json.dumps(runs, indent=1) + "\n")
    for page in args.page or [ROOT / "docs/src/results.md", ROOT / "train/tools/results_intro.md"]:
        write_between(Path(page), MARKERS, made)
    if sentence is not None:
        write_between(ROOT / "README.md", README_MARKERS, sentence)
    print(made)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
