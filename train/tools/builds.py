"""Regenerate the table of the classical controllers on every ball preset (docs: Bring your own platform).

Run: ``.venv/bin/python train/tools/builds.py [--episodes 100] [--workers 2] [--builds NAMES] [--controllers NAMES]
[--dither-deg D] [--section NAME] [--out docs/src/builds.md]``

Each controller (``--policy NAME``, its reference gains or design adapted to the build by
:func:`stewart_gym.control.classical_controller`) goes through :func:`stewart_gym.evaluation.evaluate` on
seeds 0…N−1 of the randomised balance task on each build, as ``stewart-gym evaluate --policy NAME
--geometry BUILD --episodes N`` does. The table replaces the text between the ``builds-table`` markers of
``--out`` (nothing else of the page changes); without the markers the script stops with one ``error:`` line (exit 2).
``--dither-deg D`` runs the controllers with D degrees of dither added to their shipped design
(:class:`stewart_gym.control.SquareWaveDither`); ``--section NAME`` picks the markers ``<!-- NAME:start -->`` …
``<!-- NAME:end -->`` (default ``builds-table``), so that one page can hold several tables.
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[2]
BALANCE = "StewartBallBalance-v0"
BUILDS = ("servo-hexapod", "memememe-liverpool", "desk-rect", "senilov2018")
CONTROLLERS = {"pid": "PID (`pid`)", "pid-kalman": "PID + Kalman (`pid-kalman`)", "lqr": "LQR (`lqr`)",
               "lqr-pid": "LQR → PID (`lqr-pid`)"}  # fmt: skip


def with_dither(name: str, dither: float) -> Any:
    """The shipped design of controller ``name`` with ``dither`` rad (both parts of the hand-over)."""
    from dataclasses import replace

    from stewart_gym.control import HandoverDesign, shipped_design

    design = shipped_design(name)
    if isinstance(design, HandoverDesign):
        return replace(design, lqr=replace(design.lqr, dither=dither), pid=replace(design.pid, dither=dither))
    return replace(design, dither=dither)


def run_job(job: dict[str, Any]) -> dict[str, Any]:
    """One evaluation (in a worker process)."""
    import math

    from stewart_gym.control import CLASSICAL, classical_controller
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    _, policy, env_kwargs = load_for_evaluation(job["policy"], BALANCE, job["build"])
    if job["dither_deg"] > 0:
        design = with_dither(job["policy"], math.radians(job["dither_deg"]))
        policy = classical_controller(CLASSICAL[job["policy"]][0], design, job["build"])
    return {**job, "metrics": evaluate(BALANCE, policy, episodes=job["episodes"], seed=0, env_kwargs=env_kwargs)}


def describe(build: str) -> str:
    from stewart_gym.presets import load_preset

    geo = load_preset(build)
    width, depth = (round(v * 1e3) for v in geo.plate_extent)
    kind = ", linear" if geo.kind == "linear" else ""
    return f"{build}{kind} ({width} × {depth} mm)"


def table(results: list[dict[str, Any]]) -> str:
    rows = ["| build (plate) | controller | success | RMS error, last 5 s | final error | settling time (start) "
            "| pulse rate | peak-to-peak |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in results:
        m = r["metrics"]
        settle = "–" if m["settling_time_s"] is None else f"{m['settling_time_s']:.2f} s"
        dither = f" + {r['dither_deg']:g}° dither" if r["dither_deg"] > 0 else ""
        rows.append(f"| {describe(r['build'])} | {CONTROLLERS[r['policy']]}{dither} | {m['success_rate']:.0%} | "
                    f"{m['rms_error_mm']:.2f} mm | {m['final_error_mm']:.2f} mm | {settle} "
                    f"({m['settling_offset_mm']:.0f} mm, {m['settled_fraction']:.0%} settled) | "
                    f"{shown(m['settled_pulse_rate_us_per_s'], '{:,.0f} µs/s')} | "
                    f"{shown(m['settled_pulse_p2p_us'], '{:.0f} µs')} |")  # fmt: skip
    return "\n".join(rows)


def shown(value: float | None, pattern: str) -> str:
    """A metric as text; "–" where there is none (every episode ended with the ball off the plate)."""
    return "–" if value is None else pattern.format(value)


def names(parser: argparse.ArgumentParser, text: str, known: tuple[str, ...] | list[str], what: str) -> list[str]:
    chosen = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in chosen if n not in known]
    if unknown or not chosen:
        parser.error(f"unknown {what} {unknown or text!r}; choose from {', '.join(known)}")
    return chosen


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--builds", default=",".join(BUILDS))
    ap.add_argument("--controllers", default=",".join(CONTROLLERS))
    ap.add_argument("--dither-deg", type=float, default=0.0, help="degrees of dither added to every design")
    ap.add_argument("--section", default="builds-table", help="the markers' name on the page")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "src" / "builds.md")
    args = ap.parse_args()
    builds = names(ap, args.builds, BUILDS, "build")
    controllers = names(ap, args.controllers, list(CONTROLLERS), "controller")
    if args.episodes < 1 or args.workers < 1:
        ap.error("--episodes and --workers must be at least 1")
    if not 0 <= args.dither_deg < 10:
        ap.error(f"--dither-deg must be a number of degrees in [0, 10), got {args.dither_deg}")
    start, end = f"<!-- {args.section}:start -->", f"<!-- {args.section}:end -->"
    page = args.out.read_text(encoding="utf-8") if args.out.is_file() else ""
    if start not in page or end not in page or page.index(start) > page.index(end):
        ap.error(f"{args.out} has no {start} … {end} section to replace; add the two markers")
    jobs = [{"build": b, "policy": c, "episodes": args.episodes, "dither_deg": args.dither_deg}
            for b in builds for c in controllers]  # fmt: skip
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(run_job, jobs))
    text = table(results)
    head, rest = page.split(start, 1)
    args.out.write_text(f"{head}{start}\n{text}\n{end}{rest.split(end, 1)[1]}", encoding="utf-8")
    print(text)
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
