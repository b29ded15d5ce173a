"""Analysis speed: workspace map, sensitivity map, planar sweep, assembly modes.

Run: ``.venv/bin/python bench/bench_analysis.py [--json]``. One core (BLAS limited to one thread).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from stewart_gym.analysis.assembly import assembly_modes  # noqa: E402
from stewart_gym.analysis.planar import PLANAR_PRESETS, sweep_strut  # noqa: E402
from stewart_gym.analysis.sensitivity import sensitivity, xy_grid_poses  # noqa: E402
from stewart_gym.analysis.workspace import height_map  # noqa: E402
from stewart_gym.kinematics import inverse_kinematics  # noqa: E402
from stewart_gym.presets import load_preset  # noqa: E402


def best(fn, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    geo = load_preset("servo-hexapod")
    xs = np.linspace(-0.06, 0.06, 100)
    levels = np.arange(-300, 301) * 1e-4  # ±30 mm at 0.1 mm: 601 levels
    res = {
        "workspace_map_100x100_0.1mm_s": best(lambda: height_map(geo, x=xs, y=xs, z_levels=levels)),
        "workspace_map_levels": len(levels),
        "sensitivity_61x61_s": best(lambda: sensitivity(geo, xy_grid_poses(np.linspace(-0.05, 0.05, 61),
                                                                            np.linspace(-0.05, 0.05, 61)))),
        "planar_sweep_231_lengths_s": best(lambda: sweep_strut(PLANAR_PRESETS["sauer"], "p2",
                                                               np.linspace(0.5, 12, 231)), 1),
    }  # fmt: skip
    senilov = load_preset("senilov2018")
    lengths = inverse_kinematics(senilov, np.array([0.01, 0, 0, 0.05, 0.02, 0.1])).leg_lengths
    res["assembly_modes_4000_guesses_s"] = best(lambda: assembly_modes(senilov, lengths, guesses=4000), 1)
    if args.json:
        print(json.dumps(res))
        return
    print(f"workspace map, 100×100 grid × {len(levels)} z levels (0.1 mm): {res['workspace_map_100x100_0.1mm_s']:.3f} s "
          "(target ≤ 2 s)")
    print(f"sensitivity map, 61×61 poses:                 {res['sensitivity_61x61_s']:.3f} s")
    print(f"planar 3-RPR sweep, 231 strut lengths:        {res['planar_sweep_231_lengths_s']:.3f} s")
    print(f"assembly modes, 4000 Newton starts:           {res['assembly_modes_4000_guesses_s']:.3f} s")


if __name__ == "__main__":
    main()
