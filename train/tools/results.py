"""Regenerate the docs' results page: learned vs PID vs LQR on every task and metric, with robustness.

Run: ``.venv/bin/python train/tools/results.py [--recipe "LABEL=runs/s0,runs/s1,runs/s2" ...] [--episodes 100]
[--robust-episodes 50] [--workers 2] [--out docs/src/results.md] [--recipes-only | --rows LABELS | --from-json]
[--tables KINDS]``
(``--recipes-only``: evaluate only the given recipes' runs and keep the rest of ``results.json``, the other
recipes included;
``--rows "LQR → PID"``: evaluate only those controllers and keep the rest; ``--tables pushes``: evaluate only
those tables (:data:`TABLE_KINDS`) and keep the rest; both together: those controllers in those tables.)

Every controller goes through :func:`stewart_gym.evaluation.evaluate` on the same seeded, domain-randomised
episodes (seeds 0…N−1). Rows:

* ``shipped PPO``: the shipped learned policy of the task (behind the low-pass observer it was trained with);
* ``residual PPO``: the shipped residual policy (``--policy shipped-residual``: a learned correction of the
  LQR → PID's approach, for balance and for track);
* ``PID``: the tuned cascaded PID behind the low-pass observer (its tuning), and ``PID + Kalman``, the PID
  retuned behind the Kalman observer (``--policy pid-kalman``);
* ``LQR``: the LQR behind the Kalman observer;
* ``LQR → PID``: the LQR bringing the ball in, the PID + Kalman holding it (``--policy lqr-pid``);
* ``--recipe LABEL=RUN,RUN,RUN`` (repeatable): run folders of one recipe trained with different seeds: each is
  evaluated on its task (a tracker on every trajectory), and the page gives a column per recipe with their
  mean and range (the spread over training seeds, not the best run).

Pushes: every controller on ``StewartBallDisturbance-v0`` (impulses on the ball and a load on the plate; the
balance policies, none trained or tuned with pushes), with the residual paired against the classical controllers.
The same table goes into the Environments page between :data:`PUSHES_MARKERS`.

Robustness: success on the balance task with the touch panel's latency, then its noise, fixed at each value
(the rest of the randomisation as usual), and the settled servo motion against the noise. results.json keeps
each seed's values for every balance, track and pushes row: the paired comparisons (row minus row, seed by
seed, on balance, on each trajectory and under pushes) and the balance table's median settling time come from them.

Writes the page (Markdown: train/tools/results_intro.md with the tables where it says :data:`TABLES_MARKER`),
``results.json`` beside it and ``images/robustness.png``; for the docs' own page also the README's headline
table (:func:`headline`, between :data:`README_MARKERS`) and the Environments page's pushes table
(:func:`pushes`, between :data:`PUSHES_MARKERS`).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[2]
BALANCE, TRACK, PUSHED = "StewartBallBalance-v0", "StewartBallTrack-v0", "StewartBallDisturbance-v0"
TRAJECTORIES = ("circle", "figure8", "waypoints")
#: label → (policy, estimator or None for the policy's own)
CONTROLLERS = {"shipped PPO": ("shipped", None), "residual PPO": ("shipped-residual", None), "PID": ("pid", None),
               "PID + Kalman": ("pid-kalman", None), "LQR": ("lqr", None), "LQR → PID": ("lqr-pid", None)}  # fmt: skip
ROBUST = ("shipped PPO", "residual PPO", "PID", "PID + Kalman", "LQR", "LQR → PID")
METRICS = [("success_rate", "success", "{:.0%}"), ("rms_error_mm", "RMS error, last 5 s (mm)", "{:.2f}"),
           ("final_error_mm", "final error (mm)", "{:.2f}"), ("settling_time_s", "settling time from 100 mm (s)",
                                                              "{:.2f}"),
           ("settled_pulse_rate_us_per_s", "settled pulse rate (µs/s per servo)", "{:.0f}"),
           ("settled_pulse_p2p_us", "settled peak-to-peak (µs, largest channel)", "{:.0f}"),
           ("fell_rate", "ball fell off", "{:.0%}")]  # fmt: skip
#: The paired comparisons on the balance table (row minus row, seed by seed) and their metrics (lower is better).
PAIRS = (("residual PPO", "PID + Kalman"), ("residual PPO", "LQR"), ("residual PPO", "LQR → PID"),
         ("shipped PPO", "PID + Kalman"), ("shipped PPO", "LQR"), ("LQR → PID", "PID + Kalman"),
         ("LQR → PID", "LQR"))  # fmt: skip
PAIRED = (("rms_error_mm", "RMS error, last 5 s (mm)"), ("final_error_mm", "final error (mm)"),
          ("settling_time_s", "settling time (s)"))  # fmt: skip
#: The paired comparisons on each track table: the shipped residual against the closest classical tracker (the
#: PID + Kalman, with the target's acceleration fed forward) and the ones it builds on.
TRACK_PAIRS = (("residual PPO", "PID + Kalman"), ("residual PPO", "LQR"), ("residual PPO", "LQR → PID"))
#: A row of the balance table computed from each seed's values rather than kept by ``evaluate``: the median of
#: the settling times (the mean is the issue's metric; a few slow starts move it, not the median).
MEDIAN_SETTLING = ("settling_median_s", "median settling time (s)", "{:.2f}")
#: The README's headline (balance): the shipped learned policies against the classical controllers, and the
#: shipped residual paired with the best two; written between these markers when the docs page is regenerated.
HEADLINE = ("residual PPO", "PID + Kalman", "LQR", "LQR → PID", "PID", "shipped PPO")
HEADLINE_PAIRS = (("residual PPO", "PID + Kalman"), ("residual PPO", "LQR"))
README_MARKERS = ("<!-- headline:start -->", "<!-- headline:end -->")
#: Where the tables go in train/tools/results_intro.md (the page's top, before the controllers and the findings); an
#: intro without it gets them at its end.
TABLES_MARKER = "<!-- tables -->"
LATENCIES_MS = (5, 25, 50, 75, 100)
NOISES_MM = (0.5, 2.0, 4.0, 8.0)
ROBUSTNESS = ("latency", "noise")
#: What ``--tables`` can name: a table's first word (``track`` is the three trajectories).
TABLE_KINDS = ("balance", "track", "pushes", "latency", "noise")
#: The pushes table's rows (``StewartBallDisturbance-v0``): the pushes go on until 7.5 s, into the last 5 s, so
#: the pulse rate is the whole episode's and the settling time is when the ball stays within 10 mm for good.
PUSH_METRICS = [("success_rate", "success", "{:.0%}"), ("fell_rate", "ball fell off", "{:.0%}"),
                ("rms_error_mm", "RMS error, last 5 s (pushes until 7.5 s; mm)", "{:.2f}"),
                ("final_error_mm", "final error (mm)", "{:.2f}"),
                ("settling_time_s", "time until it stays within 10 mm (100 mm start; pushes until 7.5 s; s)",
                 "{:.2f}"),
                ("max_tilt_deg", "largest tilt (°)", "{:.1f}"),
                ("pulse_rate_us_per_s", "pulse rate, whole episode (µs/s per servo)", "{:.0f}")]  # fmt: skip
#: The pushes table's paired comparisons: the shipped residual against the classical controllers.
PUSH_PAIRS = (("residual PPO", "PID + Kalman"), ("residual PPO", "LQR"), ("residual PPO", "LQR → PID"))
PUSHES_MARKERS = ("<!-- pushes:start -->", "<!-- pushes:end -->")


def run_job(job: dict[str, Any]) -> dict[str, Any]:
    """One evaluation (in a worker process): load the policy there, evaluate, return the metrics."""
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    source, policy, env_kwargs = load_for_evaluation(job["policy"], job["env"], None, job["estimator"])
    env_kwargs = {**env_kwargs, **job.get("env_kwargs", {})}
    metrics = evaluate(job["env"], policy, episodes=job["episodes"], seed=0, env_kwargs=env_kwargs)
    kept = {k: v for k, v in metrics.items() if isinstance(v, (int, float)) or v is None}
    if job["table"] not in ROBUSTNESS:  # each seed's values, for the paired comparisons (0.1 µm, 0.1 ms)
        kept["per_episode"] = {k: [v if v is None or isinstance(v, (bool, int)) else round(v, 4) for v in values]
                               for k, values in metrics["per_episode"].items() if values is not None}  # fmt: skip
    return {**job, "metrics": kept}


def jobs_for(args: argparse.Namespace) -> list[dict[str, Any]]:
    jobs = []
    for label, (policy, estimator) in CONTROLLERS.items():
        jobs.append({"table": "balance", "row": label, "policy": policy, "estimator": estimator, "env": BALANCE,
                     "episodes": args.episodes})  # fmt: skip
        for trajectory in TRAJECTORIES:
            jobs.append({"table": f"track {trajectory}", "row": label, "policy": policy, "estimator": estimator,
                         "env": TRACK, "episodes": args.episodes, "env_kwargs": {"trajectory": trajectory}})  # fmt: skip
        jobs.append({"table": "pushes", "row": label, "policy": policy, "estimator": estimator, "env": PUSHED,
                     "episodes": args.episodes})  # fmt: skip
    from stewart_gym.registry import resolve_policy

    for label, runs in args.recipes.items():
        for run in runs:
            row = {"row": f"seed:{run}", "recipe": label, "policy": run, "estimator": None, "episodes": args.episodes}
            if resolve_policy(run).env_id == TRACK:  # a tracker: on every trajectory
                jobs += [{**row, "table": f"track {t}", "env": TRACK, "env_kwargs": {"trajectory": t}}
                         for t in TRAJECTORIES]  # fmt: skip
            else:
                jobs.append({**row, "table": "balance", "env": BALANCE})
    for label in ROBUST:
        policy, estimator = CONTROLLERS[label]
        for ms in LATENCIES_MS:
            jobs.append({"table": "latency", "row": label, "value": ms, "policy": policy, "estimator": estimator,
                         "env": BALANCE, "episodes": args.robust_episodes,
                         "env_kwargs": {"randomization": {"sensor_latency_s": [ms / 1e3, ms / 1e3]}}})  # fmt: skip
        for mm in NOISES_MM:
            jobs.append({"table": "noise", "row": label, "value": mm, "policy": policy, "estimator": estimator,
                         "env": BALANCE, "episodes": args.robust_episodes,
                         "env_kwargs": {"randomization": {"sensor_noise_mm": [mm, mm]}}})  # fmt: skip
    return jobs


def fmt(value: Any, pattern: str) -> str:
    return "–" if value is None or value != value else pattern.format(value)


def spread(values: list[float], pattern: str) -> str:
    """Mean and range over training seeds."""
    if not values:
        return "–"
    return f"{fmt(statistics.mean(values), pattern)} ({fmt(min(values), pattern)}–{fmt(max(values), pattern)})"


def recipe(text: str) -> tuple[str, list[str]]:
    """``LABEL=RUN,RUN,RUN``: a recipe's label and the run folders of its training seeds."""
    label, sep, runs = text.partition("=")
    if not sep or not label.strip() or not runs.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: give LABEL=RUN,RUN,RUN")
    return label.strip(), [r.strip() for r in runs.split(",") if r.strip()]


def tables(results: list[dict[str, Any]], recipes: dict[str, list[str]]) -> str:
    out = scorecard(results)
    for table in ["balance", *(f"track {t}" for t in TRAJECTORIES)]:
        rows = {r["row"]: r["metrics"] for r in results if r["table"] == table}
        columns = list(CONTROLLERS)
        metrics = balance_metrics() if table == "balance" else [m for m in METRICS if m[0] != "settling_time_s"]
        seeds = {label: [rows[f"seed:{run}"] for run in runs if f"seed:{run}" in rows]
                 for label, runs in recipes.items()}  # fmt: skip
        seeds = {label: got for label, got in seeds.items() if got}
        header = "| metric | " + " | ".join(columns + [f"{label}, {len(got)} training seeds"
                                                     for label, got in seeds.items()]) + " |"  # fmt: skip
        out += [f"### {table.capitalize()}", "", header, "|---" * (len(columns) + 1 + len(seeds)) + "|"]
        for key, name, pattern in metrics:
            cells = [fmt(metric(rows[c], key), pattern) if c in rows else "–" for c in columns]
            for got in seeds.values():
                cells.append(spread([v for m in got if (v := metric(m, key)) is not None], pattern))
            out.append(f"| {name} | " + " | ".join(cells) + " |")
        out.append("")
    out += paired(results) + paired_track(results) + pushes_section(results)
    for table, unit, values in (("latency", "ms", LATENCIES_MS), ("noise", "mm", NOISES_MM)):
        rows = {(r["row"], r["value"]): r["metrics"] for r in results if r["table"] == table}
        out += [f"### Success against the panel's {table} (balance, {unit}; in brackets the RMS error over the "
                "last 5 s)", "", "| controller | " + " | ".join(f"{v:g} {unit}" for v in values) + " |",
                "|---" * (len(values) + 1) + "|"]  # fmt: skip
        for label in ROBUST:
            out.append(f"| {label} | " + " | ".join(robust_cell(rows.get((label, v))) for v in values) + " |")
        out.append("")
    return "\n".join(out + servo_noise(results))


def balance_metrics() -> list[tuple[str, str, str]]:
    """The balance table's rows: :data:`METRICS` with :data:`MEDIAN_SETTLING` after the (mean) settling time."""
    at = [m[0] for m in METRICS].index("settling_time_s") + 1
    return [*METRICS[:at], MEDIAN_SETTLING, *METRICS[at:]]


def metric(metrics: dict[str, Any], key: str) -> Any:
    """A metric of one evaluation; the median settling time from its seeds' values (None without them, or where
    no start settled)."""
    if key != MEDIAN_SETTLING[0]:
        return metrics.get(key)
    times = [t for t in (metrics.get("per_episode") or {}).get("settling_s") or [] if t is not None]
    return statistics.median(times) if times else None


def servo_noise(results: list[dict[str, Any]]) -> list[str]:
    """How much the servos move once the ball is held, against the panel's noise (the noise rows' settled
    peak-to-peak and pulse rate): what the sensor noise itself demands of every controller."""
    rows = {(r["row"], r["value"]): r["metrics"] for r in results if r["table"] == "noise"}
    if not rows:
        return []
    out = ["### Settled servo motion against the panel's noise (balance, mm; the largest channel's peak-to-peak "
           "over the last 5 s in µs, in brackets the pulse rate in µs/s per servo)", "",
           "| controller | " + " | ".join(f"{v:g} mm" for v in NOISES_MM) + " |", "|---" * (len(NOISES_MM) + 1) + "|"]
    for label in ROBUST:
        cells = []
        for v in NOISES_MM:
            m = rows.get((label, v)) or {}
            p2p, rate = m.get("settled_pulse_p2p_us"), m.get("settled_pulse_rate_us_per_s")
            cells.append("–" if p2p is None else f"{p2p:.0f}" + ("" if rate is None else f" ({rate:.0f})"))
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    return [*out, ""]


def robust_cell(metrics: dict[str, Any] | None) -> str:
    """A robustness table's cell: the success rate, and the RMS error in brackets where it was kept."""
    if metrics is None:
        return "–"
    rms = metrics.get("rms_error_mm")
    return fmt(metrics.get("success_rate"), "{:.0%}") + ("" if rms is None else f" ({rms:.2f} mm)")


def paired(results: list[dict[str, Any]]) -> list[str]:
    """The balance table's paired comparisons (:data:`PAIRS`): the difference on the same seeds with its 95 %
    bootstrap interval, and whether it is better, worse or a tie (the interval holds 0) at this many seeds."""
    from stewart_gym.evaluation import same_seeds

    rows = {r["row"]: r["metrics"] for r in results if r["table"] == "balance"}
    pairs = [(a, b) for a, b in PAIRS if same_seeds(rows.get(a), rows.get(b))]
    if not pairs:
        return []
    episodes = len(rows[pairs[0][0]]["per_episode"]["success"])
    out = [f"### Balance, paired: row minus row on the same {episodes} seeds", "",
           "Each cell: the difference, its 95 % bootstrap interval (2,000 resamples of the seeds, both rows "
           "resampled together), and the verdict: *better* or *worse* when the interval excludes 0, *tie* when "
           "it holds 0 (no difference shown at this many seeds); no verdict on fewer than 10 paired seeds. Settling "
           "compares the seeds where both settled.", "",
           "| rows | " + " | ".join(name for _, name in PAIRED) + " |", "|---" * (len(PAIRED) + 1) + "|"]  # fmt: skip
    out += [f"| {a} − {b} | " + " | ".join(paired_cells(rows[a], rows[b])) + " |" for a, b in pairs]
    return [*out, ""]


def paired_track(results: list[dict[str, Any]]) -> list[str]:
    """The track tables' paired comparisons (:data:`TRACK_PAIRS`, RMS and final error), one line per trajectory
    and pair where both rows kept their seeds' values."""
    from stewart_gym.evaluation import same_seeds

    lines = []
    for trajectory in TRAJECTORIES:
        rows = {r["row"]: r["metrics"] for r in results if r["table"] == f"track {trajectory}"}
        lines += [f"| {trajectory}: {a} − {b} | " + " | ".join(paired_cells(rows[a], rows[b], PAIRED[:2])) + " |"
                  for a, b in TRACK_PAIRS if same_seeds(rows.get(a), rows.get(b))]  # fmt: skip
    if not lines:
        return []
    return ["### Track, paired: row minus row on the same seeds", "",
            "As for balance: the difference, its 95 % bootstrap interval, and the verdict.", "",
            "| trajectory: rows | " + " | ".join(name for _, name in PAIRED[:2]) + " |", "|---" * 3 + "|",
            *lines, ""]  # fmt: skip


#: The scorecard (:func:`scorecard`): the shipped learned controller against the best classical controllers (the
#: retuned PID, behind the Kalman observer, and the LQR) and the classical base it corrects (the LQR → PID), on
#: the balance and track tables.
SCORE_ROW, SCORE_AGAINST = "residual PPO", ("PID + Kalman", "LQR", "LQR → PID")
SCORE_PAIRED = (("success_rate", "success", "{:+.0%}"), ("rms_error_mm", "RMS error, last 5 s", "{:+.2f} mm"),
                ("final_error_mm", "final error", "{:+.2f} mm"), ("settling_time_s", "settling time", "{:+.2f} s"))
SCORE_SERVO = (("settled_pulse_rate_us_per_s", "settled pulse rate", "µs/s"),
               ("settled_pulse_p2p_us", "settled peak-to-peak", "µs"))  # fmt: skip


def scorecard(results: list[dict[str, Any]]) -> list[str]:
    """The shipped learned controller (:data:`SCORE_ROW`) against each of :data:`SCORE_AGAINST`, one line per
    table and opponent, every metric in one cell: the paired verdict and difference for success, RMS error, final
    error and settling (balance only), and for the settled servo motion whether it is at most the opponent's
    (both as the tables round them: the servo figures are per evaluation, not per seed). Then the count of each
    verdict. Nothing where no table has both rows on the same seeds."""
    from stewart_gym.evaluation import paired_difference, paired_verdict, same_seeds

    lines, counts = [], dict.fromkeys(("better", "tie", "worse", "≤", "more"), 0)
    for table in ["balance", *(f"track {t}" for t in TRAJECTORIES)]:
        rows = {r["row"]: r["metrics"] for r in results if r["table"] == table}
        for other in SCORE_AGAINST:
            a, b = rows.get(SCORE_ROW), rows.get(other)
            if not same_seeds(a, b):
                continue
            cells = []
            for key, _, pattern in SCORE_PAIRED:
                if a.get(key) is None or b.get(key) is None:
                    cells.append("–")
                    continue
                diff, low, high = paired_difference(a, b, key)
                verdict = paired_verdict(key, low, high)
                counts[verdict] = counts.get(verdict, 0) + 1
                cells.append(f"{verdict} ({pattern.format(diff)})")
            for key, _, unit in SCORE_SERVO:
                if a.get(key) is None or b.get(key) is None:
                    cells.append("–")
                    continue
                mine, theirs = round(a[key]), round(b[key])
                verdict = "≤" if mine <= theirs else "more"
                counts[verdict] += 1
                cells.append(f"{verdict} ({mine} / {theirs} {unit})")
            lines.append(f"| {table}: {other} | " + " | ".join(cells) + " |")
    if not lines:
        return []
    names = [name for _, name, _ in SCORE_PAIRED] + [name for _, name, _ in SCORE_SERVO]
    tally = (f"{counts['better']} better, {counts['tie']} tie, {counts['worse']} worse; the servo motion at most the "
             f"other's in {counts['≤']} of {counts['≤'] + counts['more']}")
    held = next((r["metrics"].get("settled_pulse_p2p_us") for r in results
                 if r["table"] == "balance" and r["row"] == SCORE_ROW), None)  # fmt: skip
    marks = (f" Holding the ball (balance) its settled peak-to-peak is {held:.0f} µs, against a mark of 30 µs: what "
             "the panel's noise demands is the finding \"Servos\" below." if held is not None else "")
    against = ", the ".join(SCORE_AGAINST[:-1]) + " and the " + SCORE_AGAINST[-1]
    return [f"### At a glance: the {SCORE_ROW} against the {against}", "",
            "What this page measures: whether the learned controller is at least as good as the best classical "
            "ones on success, RMS error, final error and settling, while moving the servos no more than the PID "
            "(here the PID + Kalman); the LQR → PID is the classical controller it corrects. Each line pairs the "
            f"{SCORE_ROW} with one of them on one table's seeds: the verdict of the paired comparison with the "
            "difference (the paired tables below give the intervals of the errors and settling), and for the "
            f"settled servo motion whether it is at most the other's (its figure / the other's). In all: "
            f"{tally}.{marks}", "",
            "| table: against | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|", *lines, ""]  # fmt: skip


def paired_cells(a: dict[str, Any], b: dict[str, Any],
                 metrics: tuple[tuple[str, str], ...] = PAIRED) -> list[str]:  # fmt: skip
    """Row ``a`` minus row ``b`` (their metrics with ``per_episode``) on each of ``metrics`` (:data:`PAIRED`): the
    difference, its 95 % bootstrap interval and the verdict (better, worse, or tie when the interval holds 0)."""
    from stewart_gym.evaluation import paired_count, paired_difference, paired_verdict

    cells = []
    for key, _ in metrics:
        diff, low, high = paired_difference(a, b, key)
        cells.append(f"{diff:+.2f} [{low:+.2f}, {high:+.2f}] {paired_verdict(key, low, high, paired_count(a, b, key))}")
    return cells


def compared_table(results: list[dict[str, Any]], table: str, columns: Any, metrics: list[tuple[str, str, str]],
                   pairs: tuple[tuple[str, str], ...], pairs_heading: str) -> str:
    """One table's ``columns`` (controller labels, those it has) on ``metrics``, titled with the seed count, and
    the ``pairs`` whose rows kept their values on the same seeds, each with its difference, interval and verdict on
    :data:`PAIRED` (the README's headline, the pushes table); "" where the table has no rows."""
    from stewart_gym.evaluation import same_seeds

    rows = {r["row"]: r["metrics"] for r in results if r["table"] == table}
    if not rows:
        return ""
    columns = [c for c in columns if c in rows]
    episodes = {rows[c].get("episodes") for c in columns}
    title = f"{table}, {episodes.pop()} seeds" if len(episodes) == 1 and None not in episodes else table
    out = [f"| {title} | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    out += [f"| {name} | " + " | ".join(fmt(metric(rows[c], key), pattern) for c in columns) + " |"
            for key, name, pattern in metrics]  # fmt: skip
    pairs = [(a, b) for a, b in pairs if same_seeds(rows.get(a), rows.get(b))]
    if pairs:
        out += ["", f"| {pairs_heading} | " + " | ".join(name for _, name in PAIRED) + " |",
                "|---" * (len(PAIRED) + 1) + "|"]  # fmt: skip
        out += [f"| {a} − {b} | " + " | ".join(paired_cells(rows[a], rows[b])) + " |" for a, b in pairs]
    return "\n".join(out)


def pushes(results: list[dict[str, Any]]) -> str:
    """The pushes table (every controller on ``StewartBallDisturbance-v0``, :data:`PUSH_METRICS`) and the
    residual's paired comparisons (:data:`PUSH_PAIRS`); "" without pushes rows."""
    return compared_table(results, "pushes", CONTROLLERS, PUSH_METRICS, PUSH_PAIRS,
                          "pushes, paired seed by seed (95 % interval)")


def pushes_section(results: list[dict[str, Any]]) -> list[str]:
    """The Control page's pushes section: :func:`pushes` under its heading (nothing without pushes rows)."""
    table = pushes(results)
    if not table:
        return []
    return [f"### Pushes (`{PUSHED}`; the balance policies, none trained or tuned with pushes)", "",
            "Impulses on the ball and a load on the plate (the Environments page). The paired rows: as for balance; "
            "settling compares the seeds where both settled.", "", table, ""]  # fmt: skip


def headline(results: list[dict[str, Any]]) -> str:
    """The README's headline table (:data:`HEADLINE` on the balance task) and the shipped residual's paired
    comparisons (:data:`HEADLINE_PAIRS`), from the results."""
    return compared_table(results, "balance", HEADLINE, balance_metrics(), HEADLINE_PAIRS,
                          "paired, seed by seed (95 % interval)")


def write_between(path: Path, markers: tuple[str, str], table: str) -> None:
    """Replace the text between ``markers`` in the file ``path`` with ``table`` (the README's headline, the
    Environments page's pushes table)."""
    text = path.read_text()
    start, end = markers
    if start not in text or end not in text:
        raise SystemExit(f"error: {path} has no {start} … {end} section for its table")
    head, rest = text.split(start, 1)
    path.write_text(head + start + "\n" + table + "\n" + end + rest.split(end, 1)[1])


def plot(results: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, (table, unit, values) in zip(axes, (("latency", "ms", LATENCIES_MS), ("noise", "mm", NOISES_MM))):
        for label in ROBUST:
            ys = [next((100 * r["metrics"]["success_rate"] for r in results if r["table"] == table
                        and r["row"] == label and r["value"] == v), None) for v in values]  # fmt: skip
            ax.plot(values, ys, marker="o", label=label)
        ax.set(xlabel=f"touch-panel {table} [{unit}]", ylabel="success [%]", ylim=(-5, 105))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("StewartBallBalance-v0: success against sensing latency and noise (randomised episodes)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def in_place(before: list[dict[str, Any]], kept: list[dict[str, Any]], fresh: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The kept rows and the freshly evaluated ones, in the order the rows had ``before`` (a re-evaluated row
    where its old one was; new rows last), so that results.json changes only where values do."""

    def key(r: dict[str, Any]) -> str:
        return json.dumps([r["table"], r["row"], r.get("value"), r.get("env_kwargs")], sort_keys=True)

    order = {key(r): i for i, r in enumerate(before)}
    return sorted(kept + fresh, key=lambda r: order.get(key(r), len(order)))


def add_recipe_runs(recipes: dict[str, list[str]], rows: list[dict[str, Any]]) -> None:
    """Add the run of each recipe row (``seed:RUN``) of ``rows`` to its recipe's list in ``recipes``, once (a
    tracker's run has a row per trajectory)."""
    for r in rows:
        if r["row"].startswith("seed:") and r["row"][5:] not in recipes.setdefault(r["recipe"], []):
            recipes[r["recipe"]].append(r["row"][5:])


def page(intro: str, tables_text: str) -> str:
    """The page: ``intro`` with ``tables_text`` in place of :data:`TABLES_MARKER` (at its end without one)."""
    if TABLES_MARKER in intro:
        before, after = intro.split(TABLES_MARKER, 1)
        return before.rstrip() + "\n\n" + tables_text.rstrip() + "\n\n" + after.lstrip()
    return intro.rstrip() + "\n\n" + tables_text


def results_page(results: list[dict[str, Any]]) -> str:
    """The whole page (Markdown) for these evaluations: train/tools/results_intro.md with the tables, each recipe's
    column where its rows are."""
    columns: dict[str, list[str]] = {}  # each recipe's column where its rows are in results.json
    add_recipe_runs(columns, results)
    intro = (ROOT / "train" / "tools" / "results_intro.md").read_text()
    text = page(intro, tables(results, columns) + "\n![robustness](images/robustness.png)\n")
    return (f"<!-- generated by train/tools/results.py on {len(results)} evaluations; edit "
            "train/tools/results_intro.md -->\n" + text.lstrip())  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--recipe", type=recipe, action="append", default=[],
                    help="LABEL=RUN,RUN,RUN: run folders of one recipe, trained with different seeds (repeatable)")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--robust-episodes", type=int, default=50)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--out", default=str(ROOT / "docs/src/results.md"))
    ap.add_argument("--from-json", action="store_true", help="rebuild the page from results.json beside it (after "
                                                             "editing train/tools/results_intro.md), evaluating nothing")
    ap.add_argument("--recipes-only", action="store_true", help="evaluate only the --recipe runs; keep the rest "
                                                                "of results.json beside the page (a recipe of the "
                                                                "same label is replaced)")
    ap.add_argument("--rows", type=lambda t: [v.strip() for v in t.split(",") if v.strip()],
                    help="evaluate only these controllers (labels, comma-separated, e.g. 'LQR → PID') and keep the "
                         "rest of results.json beside the page")  # fmt: skip
    ap.add_argument("--tables", type=lambda t: [v.strip() for v in t.split(",") if v.strip()],
                    help=f"evaluate only these tables (comma-separated, of {', '.join(TABLE_KINDS)}) and keep the "
                         "rest of results.json beside the page; with --rows, those controllers in those tables")  # fmt: skip
    args = ap.parse_args()
    out = Path(args.out)
    args.recipes = dict(args.recipe)
    unknown = [r for r in args.rows or [] if r not in CONTROLLERS]
    if unknown:
        ap.error(f"--rows: unknown controller(s) {unknown}; known: {list(CONTROLLERS)}")
    unknown = [t for t in args.tables or [] if t not in TABLE_KINDS]
    if unknown:
        ap.error(f"--tables: unknown table(s) {unknown}; known: {list(TABLE_KINDS)}")
    if args.recipes_only and not args.recipes:
        ap.error("--recipes-only needs at least one --recipe")
    saved = out.parent / "results.json"
    docs_page = out.resolve() == (ROOT / "docs/src/results.md").resolve()  # the README's and Environments' tables too
    for path, (start, end) in ((ROOT / "README.md", README_MARKERS),
                               (ROOT / "docs/src/environments.md", PUSHES_MARKERS)) if docs_page else ():  # fmt: skip
        if start not in path.read_text() or end not in path.read_text():  # before the evaluations, not after
            ap.error(f"{path} has no {start} … {end} section for its table")
    if (args.from_json or args.rows or args.tables or args.recipes_only) and not saved.is_file():
        ap.error(f"{saved} not found: --from-json, --rows, --tables and --recipes-only keep the rows of an earlier "
                 "run's results.json beside the page; run without them first")  # fmt: skip
    if args.from_json:
        results = json.loads(saved.read_text())
    else:
        from stewart_gym.errors import PolicyError

        try:
            jobs = jobs_for(args)  # resolves every --recipe run before the first evaluation starts
        except PolicyError as exc:
            ap.error(f"--recipe: {exc}")
        before: list[dict[str, Any]] = []  # the rows kept from results.json (--rows, --recipes-only)
        kept: list[dict[str, Any]] = []
        if args.rows or args.tables:

            def chosen(r: dict[str, Any]) -> bool:  # a controller's row (not a recipe's) of those rows and tables
                return (not r["row"].startswith("seed:") and (not args.rows or r["row"] in args.rows)
                        and (not args.tables or r["table"].split()[0] in args.tables))

            before = json.loads(saved.read_text())
            kept = [r for r in before if not chosen(r)]
            jobs = [j for j in jobs if chosen(j)]
        elif args.recipes_only:
            before = json.loads(saved.read_text())
            kept = [r for r in before if not r["row"].startswith("seed:") or r["recipe"] not in args.recipes]
            jobs = [j for j in jobs if j["row"].startswith("seed:")]
        with ProcessPoolExecutor(args.workers) as pool:
            results = in_place(before, kept, list(pool.map(run_job, jobs)))
        saved.write_text(json.dumps(results, indent=1, default=str) + "\n")
    plot(results, out.parent / "images" / "robustness.png")
    out.write_text(results_page(results))
    written = [out, out.parent / "images" / "robustness.png"] + ([] if args.from_json else [saved])
    if docs_page:  # the docs' page: the README's headline and the Environments page's pushes table too
        write_between(ROOT / "README.md", README_MARKERS, headline(results))
        written.append(ROOT / "README.md")
        if pushes(results):
            write_between(ROOT / "docs/src/environments.md", PUSHES_MARKERS, pushes(results))
            written.append(ROOT / "docs/src/environments.md")
    print("wrote " + ", ".join(str(path) for path in written))


if __name__ == "__main__":
    main()
