"""How fast could the ball settle? A lower bound for the settling test, to set controllers' times against.

Run: ``.venv/bin/python -m train.experiments.settling_bound [--episodes 100] [--offset-mm 100] [--radius-mm 10]
[--max-tilt-deg 10]``

For each start of the settling test of :func:`stewart_gym.evaluation.evaluate` (at rest, ``--offset-mm`` from
the target, at the angles 2πk/N, k < N = ``--episodes``), :func:`stewart_gym.analysis.settling.fastest_settling` gives
the fewest control periods after which some command sequence, each plate axis within ±``--max-tilt-deg``,
keeps the ball within ``--radius-mm`` (the success radius) to the end, under the LQR's linear model (rolling
ball, one period of dead time, the tilt's 19 ms lag). Prints the bound per start angle and its mean: the
evaluation's mean settling time of a controller on the same N starts compares with that mean.
"""

from __future__ import annotations

import argparse
import math
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def run(argv: list[str] | None = None) -> None:
    """Run the experiment with the options of its command line (``argv``; default ``sys.argv[1:]``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episodes", type=int, default=100, help="starts on the circle (the evaluation's episodes)")
    ap.add_argument("--offset-mm", type=float, default=100.0, help="the start's distance from the target")
    ap.add_argument("--radius-mm", type=float, default=10.0, help="the success radius")
    ap.add_argument("--max-tilt-deg", type=float, default=10.0, help="each plate axis' largest tilt")
    args = ap.parse_args(argv)
    if args.episodes < 1:
        ap.error("--episodes must be at least 1")
    if not (math.isfinite(args.radius_mm) and math.isfinite(args.offset_mm) and 0 < args.radius_mm < args.offset_mm
            and args.offset_mm <= 1000):  # fmt: skip
        ap.error(f"need 0 < --radius-mm < --offset-mm ≤ 1000, got {args.radius_mm} and {args.offset_mm}")
    if not (math.isfinite(args.max_tilt_deg) and 0 < args.max_tilt_deg < 45):
        ap.error(f"--max-tilt-deg must be in (0, 45), got {args.max_tilt_deg}")
    from stewart_gym.analysis.settling import fastest_settling

    r, tilt = args.offset_mm / 1e3, math.radians(args.max_tilt_deg)
    bounds = {}
    for k in range(args.episodes):
        angle = 2 * math.pi * k / args.episodes
        bounds[round(math.degrees(angle), 1)] = fastest_settling((r * math.cos(angle), r * math.sin(angle)),
                                                                 args.radius_mm / 1e3, tilt)  # fmt: skip
    print("| start angle (deg) | fastest settling (s) |\n|---|---|")
    for angle, t in bounds.items():
        print(f"| {angle:g} | {t:.2f} |")
    mean = sum(bounds.values()) / len(bounds)
    print(f"mean bound {mean:.3f} s over {len(bounds)} starts at {args.offset_mm:g} mm (radius {args.radius_mm:g} mm, "
          f"±{args.max_tilt_deg:g}° per axis)")  # fmt: skip


if __name__ == "__main__":
    run()
