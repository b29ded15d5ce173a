"""The sysid recovery table: ``identify`` then ``sysid`` on twins behind ``virtual-device --twin``, the fit
against the truth.

Run: ``.venv/bin/python train/tools/sysid_table.py [--sensor panel|camera] [--seconds 60] [--twins NAME,...]
[--keep] [--out JSON] [--page PAGE ...] [--logs DIR [--refit]]``, on a quiet machine: the board and the loop
run in real time.

For each twin of :data:`TWINS`: start ``stewart-gym virtual-device --twin T`` (a platform whose parameters the
host does not know), run ``stewart-gym identify`` through the wire for ``--seconds``, stop the board with SIGINT,
then ``stewart-gym sysid`` on the log. It writes every twin's truth, fit, uncertainties and held-out predictions
to ``--out`` (JSON; ``--keep``: the rows of twins not run stay) and the table into each ``--page`` between the
markers.

``--sensor panel`` (default): the line protocol and the board's touch panel; the recovery table
(:data:`MARKERS`, ``docs/src/sysid.json``). ``--sensor camera``: the board streams its camera's view (the
``pixy2`` preset, 316 × 208 px at 60 fps: the largest the 2-core machine renders in real time beside the loop)
and ``identify --sensor camera`` reads it; the trims table (:data:`CAMERA_MARKERS`,
``docs/src/sysid_camera.json``): each servo's trim, true against fitted.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SG = [sys.executable, "-m", "stewart_gym"]
MARKERS = ("<!-- sysid table: train/tools/sysid_table.py -->", "<!-- end sysid table -->")
CAMERA_MARKERS = ("<!-- sysid camera table: train/tools/sysid_table.py --sensor camera -->",
                  "<!-- end sysid camera table -->")  # fmt: skip
#: The camera the board streams (it writes the config ``identify`` reads the stream with).
CAMERA_PRESET = "pixy2"
#: The issue's bound on each servo's trim from the camera, µs.
TRIM_BOUND_US = 5.0
#: Twins spread over the plausible ranges, several outside today's randomisation (servo speed 0.8–1.1, dead band
#: 3–8 µs, trims ±15 µs, latency 5–40 ms in all, panel noise 0.5–2 mm).
TWINS: dict[str, dict] = {
    "slow-late": {"servos": {"speed_scale": 0.5, "deadband_us": 12.0, "trim_us": [30, -30, 20, -10, 0, 25],
                             "latency_ms": 50.0}, "sensor": {"noise_mm": 2.5, "latency_ms": 30.0}},
    "fast-clean": {"servos": {"speed_scale": 1.2, "deadband_us": 2.0, "trim_us": [-10, 5, 12, -8, 3, 0],
                              "latency_ms": 5.0}, "sensor": {"noise_mm": 0.6, "latency_ms": 8.0}},
    "wide-band": {"servos": {"speed_scale": 0.8, "deadband_us": 18.0, "trim_us": [20, 20, -25, 5, -15, 10],
                             "latency_ms": 20.0}, "sensor": {"noise_mm": 1.5, "latency_ms": 15.0}},
    "laggy": {"servos": {"speed_scale": 0.7, "deadband_us": 8.0, "trim_us": [-35, 10, 0, 30, -20, 15],
                         "latency_ms": 70.0}, "sensor": {"noise_mm": 1.0, "latency_ms": 25.0}},
    "mid": {"servos": {"speed_scale": 0.9, "deadband_us": 9.0, "trim_us": [20, -20, 10, -15, 5, 20],
                       "latency_ms": 25.0}, "sensor": {"noise_mm": 1.2, "latency_ms": 20.0}},
    "noisy": {"servos": {"speed_scale": 0.75, "deadband_us": 6.0, "trim_us": [15, -15, 15, -15, 15, -15],
                         "latency_ms": 30.0}, "sensor": {"noise_mm": 3.0, "latency_ms": 12.0}},
}
#: The issue's bounds: total latency ±8 ms, noise ±0.3 mm, speed ±0.15, dead band ±3 µs.
BOUNDS = {"latency": 8.0, "noise": 0.3, "speed": 0.15, "deadband": 3.0}


def twin_toml(tables: dict) -> str:
    lines = []
    for table, values in tables.items():
        lines.append(f"[{table}]")
        lines.extend(f"{k} = {json.dumps(v)}" for k, v in values.items())
    return "\n".join(lines) + "\n"


def run_twin(name: str, tables: dict, seconds: float, folder: Path, seed: int, sensor: str = "panel",
             record: bool = True) -> dict:  # fmt: skip
    """identify and sysid on the twin ``tables`` behind a virtual board; the row of the table. Leaves the twin
    (``NAME.toml``), the log (``NAME.csv``) and the fitted twin (``NAME-fitted.toml``) in ``folder``. Without
    ``record``, it fits the log already there."""
    from stewart_gym.sim import ServoSpec
    from stewart_gym.sim.stewart_sim import MARKER_FACE_HEIGHT
    from stewart_gym.sim.twin import load_twin
    from stewart_gym.sysid import fit_twin, read_log

    twin_path, link, log = folder / f"{name}.toml", folder / f"board-{name}", folder / f"{name}.csv"
    twin_path.write_text(twin_toml(tables))
    truth = load_twin(twin_path)
    protocol, board_extra, identify_extra = "line", [], ["--sensor", "panel"]
    if sensor == "camera":
        pipe, config = folder / f"camera-{name}.mjpg", folder / f"camera-{name}.toml"
        protocol = "maestro"
        board_extra = ["--camera-stream", str(pipe), "--camera", CAMERA_PRESET, "--camera-config-out", str(config)]
        identify_extra = ["--sensor", "camera", "--camera-config", str(config)]
    board_log = folder / f"{name}-board.txt"
    if record:
        board_log.write_text(_record(name, twin_path, link, log, protocol, board_extra, identify_extra, seconds, seed))
    elif not log.is_file():
        raise FileNotFoundError(f"no log {log} to fit")
    t0 = time.perf_counter()
    result = fit_twin([read_log(log)], "servo-hexapod", marker_height=MARKER_FACE_HEIGHT if sensor == "camera" else 0.0)
    fit_s = time.perf_counter() - t0
    fit = result.twin
    (folder / f"{name}-fitted.toml").write_text(fit.toml())
    row = {
        "twin": name, "seconds": seconds, "fit_s": round(fit_s, 1), "fell_off": "off the plate" in board_log.read_text(),
        "latency_true": truth.total_latency_ms, "latency_fit": round(result.total_latency_ms, 2),
        "latency_sigma": fit.sigma.get("servos.latency_ms"),
        "noise_true": truth["sensor.noise_mm"], "noise_fit": round(fit["sensor.noise_mm"], 3),
        "speed_true": truth["servos.speed_scale"], "speed_fit": round(fit["servos.speed_scale"], 3),
        "speed_sigma": fit.sigma.get("servos.speed_scale"),
        "deadband_true": truth["servos.deadband_us"], "deadband_fit": round(fit["servos.deadband_us"], 2),
        "deadband_sigma": fit.sigma.get("servos.deadband_us"),
        "undetermined": list(fit.undetermined),
        "trims_true": list(truth["servos.trim_us"]), "trims_fit": [round(v, 2) for v in fit["servos.trim_us"]],
        "trims_sigma": None if result.trim_fit is None else [round(float(v), 2) for v in result.trim_fit.sigma_us],
        "camera_frames": None if result.trim_fit is None else result.trim_fit.frames,
        "replayed": None if result.trim_fit is None else [round(result.trim_fit.servo.max_speed / ServoSpec().max_speed, 3),
                                                          result.trim_fit.servo.deadband_us],
        "prediction": {str(h): {k: round(v, 3) for k, v in p.items()} for h, p in result.prediction.items()},
        "printed": result.lines(),
    }
    for key, bound in BOUNDS.items():
        row[f"{key}_ok"] = abs(row[f"{key}_fit"] - row[f"{key}_true"]) <= bound
    print(json.dumps(row), flush=True)
    return row


def _record(name: str, twin_path: Path, link: Path, log: Path, protocol: str, board_extra: list[str],
            identify_extra: list[str], seconds: float, seed: int) -> str:  # fmt: skip
    """Run ``identify`` on a virtual board with the twin for ``seconds``, into ``log``; what the board printed."""
    board = subprocess.Popen([*SG, "virtual-device", "--protocol", protocol, "--twin", str(twin_path), "--seed",
                              str(seed), "--link", str(link), *board_extra], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        while not link.is_symlink():
            if board.poll() is not None:
                raise RuntimeError(board.communicate()[1])
            time.sleep(0.05)
        run = subprocess.run([*SG, "identify", "--port", str(link), "--protocol", protocol, *identify_extra,
                              "--duration", str(seconds), "--out", str(log), "--seed", str(seed)],
                             capture_output=True, text=True)  # fmt: skip
    finally:
        board.send_signal(signal.SIGINT)
        board_out = board.communicate(timeout=30)[0]
    if run.returncode != 0:
        raise RuntimeError(f"identify on {name} failed: {run.stdout}{run.stderr}")
    return board_out


def write_between(page: Path, markers: tuple[str, str], text: str) -> None:
    """Put ``text`` between the ``markers`` of ``page`` (a page without them is left alone)."""
    old = page.read_text() if page.is_file() else ""
    if markers[0] in old:
        before, rest = old.split(markers[0], 1)
        page.write_text(f"{before}{markers[0]}\n{text}\n{markers[1]}{rest.split(markers[1], 1)[1]}")


def prediction_cell(row: dict) -> str:
    """The held-out 1 s prediction RMS, nominal → fitted twin (mm), and the gain."""
    p = row["prediction"].get("1.0", {})
    return f"{p['nominal']:.1f} → {p['fitted']:.1f} ({p['nominal'] / p['fitted']:.1f}×)" if p else "–"


def table(rows: list[dict]) -> str:
    head = ("| twin | total latency (ms): true → fit | panel noise (mm) | servo speed (×) | dead band (µs) | "
            "1 s prediction RMS (mm): nominal → fitted |")  # fmt: skip
    out = [head, "|---|---|---|---|---|---|"]

    def cell(row: dict, key: str, fmt: str) -> str:
        mark = "" if row[f"{key}_ok"] else " ✗"
        return f"{row[f'{key}_true']:{fmt}} → {row[f'{key}_fit']:{fmt}}{mark}"

    for r in rows:
        pred = prediction_cell(r)
        out.append(f"| {r['twin']} | {cell(r, 'latency', '.1f')} | {cell(r, 'noise', '.2f')} | "
                   f"{cell(r, 'speed', '.2f')} | {cell(r, 'deadband', '.1f')} | {pred} |")  # fmt: skip
    return "\n".join(out)


def camera_table(rows: list[dict]) -> str:
    """Each servo's trim, true → fitted (± its one-sigma uncertainty), ✗ past :data:`TRIM_BOUND_US`; the servos
    the plate poses chose; the held-out prediction."""
    out = ["| twin | " + " | ".join(f"servo {i} (µs)" for i in range(6))
           + " | largest error (µs) | frames | servos (the plate's choice): speed (×), dead band (µs), true → fit "
           "| 1 s prediction RMS (mm): nominal → fitted |",
           "|---|" + "---|" * 10]  # fmt: skip
    for r in rows:
        cells = []
        for true, fit, sd in zip(r["trims_true"], r["trims_fit"], r["trims_sigma"] or [float("nan")] * 6):
            mark = "" if abs(fit - true) <= TRIM_BOUND_US else " ✗"
            cells.append(f"{true:+.0f} → {fit:+.1f} ± {sd:.1f}{mark}")
        worst = max(abs(f - t) for t, f in zip(r["trims_true"], r["trims_fit"]))
        speed, band = r["replayed"]
        replayed = f"{r['speed_true']:.2f}, {r['deadband_true']:.0f} → {speed:.2f}, {band:.0f}"
        pred = prediction_cell(r)
        out.append(f"| {r['twin']} | " + " | ".join(cells) + f" | {worst:.1f} | {r['camera_frames']} | {replayed} "
                   f"| {pred} |")  # fmt: skip
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sensor", choices=["panel", "camera"], default="panel")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--twins", help=f"comma-separated names of {sorted(TWINS)} (default all)")
    ap.add_argument("--out", help="JSON of the rows (default docs/src/sysid.json, or sysid_camera.json)")
    ap.add_argument("--page", action="append",
                    help="page to write the table into, between the markers (default: the results page and its "
                         "intro, train/tools/results_intro.md)")
    ap.add_argument("--keep", action="store_true", help="keep the rows of twins not run from --out")
    ap.add_argument("--logs", help="folder to keep each twin's files in (its twin, log, board output and fitted "
                                   "twin), to fit them again with --refit; default: a temporary folder")
    ap.add_argument("--refit", action="store_true", help="fit the logs already in --logs instead of recording")
    args = ap.parse_args(argv)
    if args.refit and not args.logs:
        ap.error("--refit fits the logs in --logs DIR: give it")
    names = args.twins.split(",") if args.twins else list(TWINS)
    missing = [n for n in names if args.refit and not (Path(args.logs) / f"{n}.csv").is_file()]
    if missing:
        ap.error(f"--refit: no log {Path(args.logs) / (missing[0] + '.csv')}; record it first (--logs without "
                 "--refit)")  # fmt: skip
    camera = args.sensor == "camera"
    out = Path(args.out or ROOT / "docs/src" / ("sysid_camera.json" if camera else "sysid.json"))
    rows = {r["twin"]: r for r in (json.loads(out.read_text()) if out.exists() and args.keep else [])}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.logs or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for name in names:
            rows[name] = run_twin(name, TWINS[name], args.seconds, folder, seed=list(TWINS).index(name),
                                  sensor=args.sensor, record=not args.refit)  # fmt: skip
    ordered = [rows[n] for n in TWINS if n in rows]
    out.write_text(json.dumps(ordered, indent=1) + "\n")
    made = camera_table(ordered) if camera else table(ordered)
    for page in args.page or [ROOT / "docs/src/results.md", ROOT / "train/tools/results_intro.md"]:
        write_between(Path(page), CAMERA_MARKERS if camera else MARKERS, made)
    print(made)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
