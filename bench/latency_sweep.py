"""Success and RMS error against the camera's sensing latency: what camera does a controller need?

Run: ``.venv/bin/python bench/latency_sweep.py [--episodes 50] [--out out/latency_sweep.png] [--json]`` (the
camera page's plot: ``--out docs/src/images/latency_sweep.png``). With ``--json`` the table is one JSON list on
stdout, and the progress lines go to stderr.

For each exposure-to-output latency from 0 to 120 ms (a camera at 60 fps, so a detection is on average another
8 ms old; the webcam preset's centroid noise and missed detections), the camera-trained shipped policy
(``shipped-camera``), the panel-trained shipped policy (``shipped``) and the tuned PID run the same seeded
episodes of ``StewartBallBalance-v0`` with domain randomisation of everything but the camera. Prints the table
and draws the plot the docs show.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from stewart_gym.camera import CAMERA_PRESETS
from stewart_gym.envs.randomization import RandomizationRanges
from stewart_gym.evaluation import evaluate
from stewart_gym.registry import load_for_evaluation

LATENCIES_MS = (0, 20, 40, 60, 80, 100, 120)
CONTROLLERS = {"camera-trained PPO": "shipped-camera", "panel-trained PPO": "shipped", "tuned PID": "pid"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--out", default="out/latency_sweep.png", help="the plot (default out/latency_sweep.png)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error("--episodes must be 1 or more")
    progress = sys.stderr if args.json else sys.stdout
    fixed_camera = RandomizationRanges(camera_latency_scale=(1.0, 1.0), camera_noise_scale=(1.0, 1.0),
                                       camera_miss_scale=(1.0, 1.0))  # fmt: skip
    rows = []
    for name, spec in CONTROLLERS.items():
        _, policy, kwargs = load_for_evaluation(spec, "StewartBallBalance-v0", None)
        for ms in LATENCIES_MS:
            camera = replace(CAMERA_PRESETS["webcam30"], name=f"{ms} ms", fps=60.0, latency_s=ms / 1e3)
            m = evaluate("StewartBallBalance-v0", policy, episodes=args.episodes, seed=2000, settling=False,
                         env_kwargs={**kwargs, "sensor": camera, "randomization": fixed_camera})  # fmt: skip
            rows.append({"controller": name, "latency_ms": ms, "success_rate": m["success_rate"],
                         "fell_rate": m["fell_rate"], "rms_error_mm": round(m["rms_error_mm"], 3)})  # fmt: skip
            print(f"  {name:20s} {ms:>4} ms: success {m['success_rate']:.0%}, fell {m['fell_rate']:.0%}, "
                  f"RMS {m['rms_error_mm']:.2f} mm", file=progress, flush=True)  # fmt: skip
    if args.json:
        print(json.dumps(rows))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    for name in CONTROLLERS:
        mine = [r for r in rows if r["controller"] == name]
        x = [r["latency_ms"] for r in mine]
        ax1.plot(x, [100 * r["success_rate"] for r in mine], "o-", label=name)
        ax2.plot(x, [r["rms_error_mm"] for r in mine], "o-", label=name)
    ax1.set(xlabel="camera latency, exposure to output (ms; 60 fps)", ylabel="success (%)", ylim=(-5, 105))
    ax2.set(xlabel="camera latency, exposure to output (ms; 60 fps)", ylabel="RMS error, last 5 s (mm)",
            yscale="log")  # fmt: skip
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    ax1.legend(loc="lower left")
    fig.suptitle(f"StewartBallBalance-v0, {args.episodes} randomised episodes per point")
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}", file=progress)


if __name__ == "__main__":
    main()
