"""The maintained tools of ``train/tools/``: the Control page, the README's headline and the pushes table kept
equal to what ``results.py`` makes of ``docs/src/results.json``; the own-platform tables; tuning; shipping a
policy."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_shipping_a_policy_refuses_an_evaluation_file_without_json_before_touching_the_package(tmp_path: Path) -> None:
    """``train/tools/ship_policy.py --eval FILE`` reads the evaluation first: a file with no JSON object is one error line
    and nothing is written or removed under ``stewart_gym/policies``; an indented JSON object is read as it is."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    sys.path.insert(0, str(root / "train" / "tools"))
    try:
        import ship_policy
    finally:
        sys.path.remove(str(root / "train" / "tools"))
    (tmp_path / "indented.json").write_text('{\n "success_rate": 1.0,\n "per_episode": {"success": [true]}\n}\n')
    assert ship_policy.read_evaluation(tmp_path / "indented.json") == {"success_rate": 1.0}
    (tmp_path / "logged.json").write_text('loading\n{"success_rate": 0.5}\n')  # evaluate's output with a log line
    assert ship_policy.read_evaluation(tmp_path / "logged.json") == {"success_rate": 0.5}
    (tmp_path / "bad.json").write_text("Traceback (most recent call last):\n")
    policies = root / "stewart_gym/policies"
    before = sorted(p.name for p in policies.iterdir())
    try:
        for bad, says in (("bad.json", "error: --eval"), ("missing.json", "error: --eval"),  # no JSON; no file
                          ("indented.json", f"error: {tmp_path / 'run'}: no model.zip")):  # a good file, no run
            proc = subprocess.run([sys.executable, str(root / "train/tools/ship_policy.py"), str(tmp_path / "run"), "--name",
                                   "never_shipped", "--eval", str(tmp_path / bad)], capture_output=True, text=True,
                                  timeout=120)  # fmt: skip
            assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
            assert proc.stderr.startswith(says) and sorted(p.name for p in policies.iterdir()) == before
    finally:
        shutil.rmtree(policies / "never_shipped", ignore_errors=True)


def test_results_page_re_evaluates_only_the_recipes_when_asked(tmp_path: Path) -> None:
    """``train/tools/results.py --recipes-only``: the recipe's runs are evaluated, the controllers' rows of
    results.json and the other recipes are kept as they were, an earlier run of the same recipe is replaced,
    and the page gets the recipe's column next to the others."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    (tmp_path / "images").mkdir()
    kept = [{"table": "balance", "row": "LQR", "policy": "lqr", "estimator": None, "env": "StewartBallBalance-v0",
             "episodes": 3, "metrics": {"success_rate": 1.0, "rms_error_mm": 1.5}},
            {"table": "balance", "row": "seed:old", "recipe": "old", "policy": "old", "estimator": None,
             "env": "StewartBallBalance-v0", "episodes": 3, "metrics": {"success_rate": 0.5}},
            {"table": "balance", "row": "seed:stale", "recipe": "quick PID", "policy": "stale", "estimator": None,
             "env": "StewartBallBalance-v0", "episodes": 3, "metrics": {"success_rate": 0.25}}]  # fmt: skip
    (tmp_path / "results.json").write_text(json.dumps(kept))
    proc = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), "--recipes-only", "--recipe",
                           "quick PID=pid", "--episodes", "1", "--workers", "1", "--out", str(tmp_path / "r.md")],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = json.loads((tmp_path / "results.json").read_text())
    assert rows[0] == kept[0] and kept[1] in rows and not any(r["row"] == "seed:stale" for r in rows)
    new = [r for r in rows if r["row"] == "seed:pid"]
    assert len(new) == 1 and new[0]["episodes"] == 1 and new[0]["recipe"] == "quick PID"
    assert 0.0 <= new[0]["metrics"]["success_rate"] <= 1.0
    page = (tmp_path / "r.md").read_text()
    assert "quick PID, 1 training seeds" in page and "old, 1 training seeds" in page
    assert page.index("old, 1 training seeds") < page.index("quick PID, 1 training seeds")  # the columns' order kept
    bad = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), "--recipes-only", "--out",
                          str(tmp_path / "r.md")], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert bad.returncode == 2 and "needs at least one --recipe" in bad.stderr


@pytest.mark.slow
def test_results_page_re_evaluates_only_the_named_controllers(tmp_path: Path) -> None:
    """``train/tools/results.py --rows "LQR → PID"``: only that controller's rows are evaluated (balance, the three
    trajectories, latency and noise), every other row of results.json is kept, recipes included, and a
    re-evaluated row takes its old row's place; an unknown label, a --recipe run that does not exist, or no
    results.json to keep rows from, is refused with one error line and exit 2."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    (tmp_path / "images").mkdir()
    kept = [{"table": "balance", "row": "LQR", "policy": "lqr", "estimator": None, "env": "StewartBallBalance-v0",
             "episodes": 3, "metrics": {"success_rate": 1.0, "rms_error_mm": 1.5}},
            {"table": "balance", "row": "LQR → PID", "policy": "lqr-pid", "estimator": None,
             "env": "StewartBallBalance-v0", "episodes": 3, "metrics": {"success_rate": 0.25}},
            {"table": "balance", "row": "seed:old", "recipe": "old", "policy": "old", "estimator": None,
             "env": "StewartBallBalance-v0", "episodes": 3, "metrics": {"success_rate": 0.5}}]  # fmt: skip
    (tmp_path / "results.json").write_text(json.dumps(kept))
    proc = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), "--rows", "LQR → PID", "--episodes",
                           "1", "--robust-episodes", "1", "--workers", "1", "--out", str(tmp_path / "r.md")],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = json.loads((tmp_path / "results.json").read_text())
    assert kept[0] in rows and kept[2] in rows and kept[1] not in rows
    new = [r for r in rows if r["row"] == "LQR → PID"]
    assert sorted({r["table"] for r in new}) == ["balance", "latency", "noise", "pushes", "track circle",
                                                  "track figure8", "track waypoints"]  # fmt: skip
    assert all(r["episodes"] == 1 and r["policy"] == "lqr-pid" for r in new) and len(new) == 14
    assert [r["env"] for r in new if r["table"] == "pushes"] == ["StewartBallDisturbance-v0"]
    assert rows[0] == kept[0] and rows[1]["row"] == "LQR → PID" and rows[1]["table"] == "balance"  # in its old place
    assert rows[2] == kept[2]  # the rows it had no place for (the tracks, the robustness) come after the kept ones
    page = (tmp_path / "r.md").read_text()
    assert "old, 1 training seeds" in page and "| pushes, 1 seeds | LQR → PID |" in page
    noise = [r for r in new if r["table"] == "noise" and r["value"] == 8.0][0]["metrics"]
    assert f"{noise['success_rate']:.0%} ({noise['rms_error_mm']:.2f} mm)" in page  # success and RMS in each cell
    per = [r for r in new if r["table"] == "balance"][0]["metrics"]["per_episode"]  # kept for paired comparisons
    assert len(per["rms_mm"]) == len(per["settling_s"]) == 1
    track = [r for r in new if r["table"].startswith("track")][0]["metrics"]["per_episode"]  # paired on the tracks
    assert len(track["rms_mm"]) == 1 and "settling_s" not in track
    assert all("per_episode" not in r["metrics"] for r in new if r["table"] in ("latency", "noise"))
    # --tables with --rows: only that controller's pushes row is evaluated again, in its place; the rest is kept
    proc = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), "--tables", "pushes", "--rows",
                           "LQR", "--episodes", "2", "--workers", "1", "--out", str(tmp_path / "r.md")],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    again = json.loads((tmp_path / "results.json").read_text())
    fresh = [r for r in again if r not in rows]
    assert [(r["table"], r["row"], r["episodes"]) for r in fresh] == [("pushes", "LQR", 2)]
    assert len(again) == len(rows) + 1 and [r for r in again if r in rows] == rows
    assert "| pushes | LQR | LQR → PID |" in (tmp_path / "r.md").read_text()  # 2 and 1 seeds: no one count
    rows = again
    for args, says in ((["--rows", "MPC"], "unknown controller"), (["--tables", "pushes,wind"], "unknown table")):
        bad = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), *args, "--out",
                              str(tmp_path / "r.md")], capture_output=True, text=True, timeout=60)  # fmt: skip
        assert bad.returncode == 2 and says in bad.stderr and "Traceback" not in bad.stderr
    bad = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), "--recipes-only", "--recipe",
                          f"X={tmp_path / 'no_run'}", "--out", str(tmp_path / "r.md")], capture_output=True, text=True,
                         timeout=60)  # fmt: skip  (a mistyped run: refused before any evaluation, results.json kept)
    assert bad.returncode == 2 and "error: --recipe: policy" in bad.stderr and "Traceback" not in bad.stderr
    assert json.loads((tmp_path / "results.json").read_text()) == rows
    (tmp_path / "empty").mkdir()  # no results.json to keep rows from: one error line, exit 2, nothing written
    bad = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), "--from-json", "--out",
                          str(tmp_path / "empty" / "r.md")], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert bad.returncode == 2 and "results.json not found" in bad.stderr and "Traceback" not in bad.stderr
    assert not any((tmp_path / "empty").iterdir())


def test_tune_handover_writes_the_best_checked_design(tmp_path: Path) -> None:
    """``train/tools/tune_handover.py`` on a 2-set grid: prints a row per set and writes the pick as a hand-over design
    that loads (the shipped LQR and PID + Kalman inside, the picked hand-over distance)."""
    import subprocess
    import sys

    from stewart_gym.control import checked_design, shipped_design

    root, out = Path(__file__).resolve().parents[2], tmp_path / "h.json"
    proc = subprocess.run([sys.executable, str(root / "train" / "tools" / "tune_handover.py"), "--episodes", "2",
                           "--handover-mm", "2,4", "--handover-mm-s", "10", "--out", str(out)],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.count("handover ") >= 2 and "best: handover" in proc.stdout
    design = checked_design(json.loads(out.read_text()), "handover")
    assert design.handover_mm in (2.0, 4.0) and design.handover_mm_s == 10.0
    assert design.lqr == shipped_design("lqr") and design.pid == shipped_design("pid-kalman")
    bad = subprocess.run([sys.executable, str(root / "train" / "tools" / "tune_handover.py"), "--handover-mm", "30",
                          "--release-mm", "20", "--out", str(tmp_path / "bad.json")],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert bad.returncode == 2 and "error:" in bad.stderr and "release_mm" in bad.stderr
    assert "Traceback" not in bad.stderr and not (tmp_path / "bad.json").exists()  # refused before any work


def test_builds_table_replaces_only_its_section(tmp_path: Path) -> None:
    """``train/tools/builds.py`` for one build and one controller, one episode: the table between the markers is
    replaced (a row per pair, every column filled) and the rest of the page is kept; with ``--dither-deg`` and
    ``--section`` a second table goes between its own markers; an unknown build, a dither of 20° and a page
    without markers are refused with one ``error:`` line before any evaluation."""
    import subprocess
    import sys

    root, page = Path(__file__).resolve().parents[2], tmp_path / "page.md"
    page.write_text("# before\n<!-- builds-table:start -->\nold table\n<!-- builds-table:end -->\nafter\n")
    script = [sys.executable, str(root / "train" / "tools" / "builds.py")]
    proc = subprocess.run([*script, "--episodes", "1", "--builds", "desk-rect", "--controllers", "lqr", "--out",
                           str(page)], capture_output=True, text=True, timeout=300, cwd=ROOT)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    text = page.read_text()
    assert text.startswith("# before\n<!-- builds-table:start -->\n| build (plate) |") and text.endswith("end -->\nafter\n")
    rows = [line for line in text.splitlines() if line.startswith("| desk-rect")]
    assert len(rows) == 1 and "LQR (`lqr`)" in rows[0] and "400 × 260 mm" in rows[0] and "old table" not in text
    assert len(rows[0].split("|")) == 10 and "–" not in rows[0] and " µs |" in rows[0]
    page.write_text(text + "<!-- shaken:start -->\n<!-- shaken:end -->\n")
    proc = subprocess.run([*script, "--episodes", "1", "--builds", "desk-rect", "--controllers", "lqr-pid",
                           "--dither-deg", "0.5", "--section", "shaken", "--out", str(page)],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    again = page.read_text()
    assert again.startswith(text) and "| desk-rect (400 × 260 mm) | LQR → PID (`lqr-pid`) + 0.5° dither |" in again
    for args, says in ((["--builds", "my-desk", "--out", str(page)], "unknown build"),
                       (["--dither-deg", "20", "--out", str(page)], "--dither-deg"),
                       (["--out", str(tmp_path / "none.md")], "markers")):  # fmt: skip
        bad = subprocess.run([*script, *args], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert bad.returncode == 2 and "error:" in bad.stderr and says in bad.stderr, bad.stderr
        assert "Traceback" not in bad.stderr


def test_results_page_pairs_rows_seed_by_seed(tmp_path: Path) -> None:
    """``train/tools/results.py --from-json``: the tables come first on the page; the paired table gives each
    difference with its interval and verdict (a shift on every seed is *better*/*worse*, a mixed one a *tie*);
    rows without per-seed values, or with them on other seeds (a row re-evaluated on fewer), are left out."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    (tmp_path / "images").mkdir()

    def row(label: str, rms: list[float], final: list[float], settle: list[float]) -> dict:
        """A row whose seeds are the given ones three times over (a verdict needs 10 paired episodes)."""
        n = 3 * len(rms)
        per = {"success": [True] * n, "rms_mm": rms * 3, "tail_steps": [250] * n, "final_mm": final * 3,
               "settling_s": settle * 3}  # fmt: skip
        return {"table": "balance", "row": label, "policy": label, "estimator": None, "env": "StewartBallBalance-v0",
                "episodes": n, "metrics": {"seed": 0, "success_rate": 1.0, "per_episode": per}}  # fmt: skip

    results = [row("LQR → PID", [1.0, 1.1, 0.9, 1.0], [0.5, 0.9, 0.4, 0.8], [0.6, 0.6, 0.7, 0.5]),
               row("PID + Kalman", [1.0, 1.0, 1.0, 1.0], [0.6, 0.6, 0.6, 0.6], [1.4, 1.5, 1.5, 1.4]),
               row("LQR", [2.0, 2.1, 1.9, 2.0], [1.0, 1.1, 0.9, 1.0], [0.6, 0.6, 0.7, 0.5])]  # fmt: skip
    del results[2]["metrics"]["per_episode"]  # an old results.json row: no paired comparison with it
    fewer = row("residual PPO", [0.9, 1.0, 1.1], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5])  # 9 seeds: not paired with 12
    results.append(fewer)
    (tmp_path / "results.json").write_text(json.dumps(results))
    proc = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), "--from-json", "--out",
                           str(tmp_path / "r.md")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    page = (tmp_path / "r.md").read_text()
    assert "paired: row minus row on the same 12 seeds" in page
    # the tables where train/tools/results_intro.md marks them: after what the rows are and how to read them
    assert "<!-- tables -->" not in page
    assert page.index("## The controllers") < page.index("## Reading the tables") < page.index("paired: row minus row")
    line = next(x for x in page.splitlines() if x.startswith("| LQR → PID − PID + Kalman |"))
    rms, final, settle = (c.strip() for c in line.split("|")[2:5])
    assert rms.endswith("tie") and final.endswith("tie") and settle.endswith("better")
    assert settle.startswith("-0.85 [")
    assert "| LQR → PID − LQR |" not in page and "| residual PPO −" not in page


def test_results_page_track_pairs_median_settling_and_servo_motion_against_noise(tmp_path: Path) -> None:
    """``train/tools/results.py --from-json``: each track table's residual is paired with the LQR seed by seed; the
    balance table gives the median settling time beside the mean (from each seed's values; "–" without them);
    the noise rows' settled peak-to-peak and pulse rate make their own table."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    (tmp_path / "images").mkdir()

    def track(label: str, rms: list[float]) -> dict:  # its seeds three times over: a verdict needs 10 pairs
        per = {"success": [True] * 12, "rms_mm": rms * 3, "tail_steps": [250] * 12, "final_mm": rms * 3}
        return {"table": "track circle", "row": label, "policy": label, "estimator": None,
                "env": "StewartBallTrack-v0", "episodes": 12, "env_kwargs": {"trajectory": "circle"},
                "metrics": {"success_rate": 1.0, "rms_error_mm": 1.0, "per_episode": per}}  # fmt: skip

    per = {"success": [True] * 4, "rms_mm": [1.0] * 4, "tail_steps": [250] * 4, "final_mm": [1.0] * 4,
           "settling_s": [0.5, 0.6, None, 2.0]}  # fmt: skip
    results = [{"table": "balance", "row": "LQR", "policy": "lqr", "estimator": None, "env": "StewartBallBalance-v0",
                "episodes": 4, "metrics": {"success_rate": 1.0, "settling_time_s": 1.03, "per_episode": per}},
               {"table": "balance", "row": "PID", "policy": "pid", "estimator": None, "env": "StewartBallBalance-v0",
                "episodes": 4, "metrics": {"success_rate": 1.0, "settling_time_s": 2.0}},
               track("residual PPO", [0.9, 1.0, 1.1, 1.2]), track("LQR", [1.0, 1.1, 1.2, 1.3]),
               {"table": "noise", "row": "LQR", "value": 2.0, "policy": "lqr", "estimator": None,
                "env": "StewartBallBalance-v0", "episodes": 4,
                "metrics": {"success_rate": 1.0, "settled_pulse_p2p_us": 81.5, "settled_pulse_rate_us_per_s": 173.2}}]
    (tmp_path / "results.json").write_text(json.dumps(results))
    proc = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), "--from-json", "--out",
                           str(tmp_path / "r.md")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = (tmp_path / "r.md").read_text().splitlines()
    header = next(x for x in lines if x.startswith("| metric | shipped PPO"))
    median = [c.strip() for c in next(x for x in lines if x.startswith("| median settling time (s) |")).split("|")]
    columns = [c.strip() for c in header.split("|")]
    assert median[columns.index("LQR")] == "0.60" and median[columns.index("PID")] == "–"  # median of 0.5, 0.6, 2.0
    pair = next(x for x in lines if x.startswith("| circle: residual PPO − LQR |"))
    rms, final = (c.strip() for c in pair.split("|")[2:4])
    assert rms.startswith("-0.10 [") and rms.endswith("better") and final.endswith("better")
    assert not any(x.startswith("| circle: residual PPO − LQR → PID |") for x in lines)  # no such row given
    noise = next(x for x in lines if x.startswith("| LQR |") and "(173)" in x)
    assert [c.strip() for c in noise.split("|")[1:6]] == ["LQR", "–", "82 (173)", "–", "–"]


def test_results_scorecard_gives_every_verdict_against_each_classical_controller() -> None:
    """The Control page's "at a glance" lines: per table, the residual against each classical controller there, the
    paired verdict and difference of each metric ("worse" shows as plainly as "better"), the settled servo motion
    against the other's as the tables round it, "–" for what a table does not measure, and the tally."""
    script = results_script()

    def row(table: str, label: str, rms: float, final: list[float], settle: float | None, rate: float | None,
            p2p: float | None) -> dict:  # fmt: skip
        per = {"success": [True] * 4, "rms_mm": [rms] * 4, "tail_steps": [250] * 4, "final_mm": final}
        metrics = {"seed": 0, "success_rate": 1.0, "rms_error_mm": rms, "final_error_mm": sum(final) / 4,
                   "per_episode": per, "settled_pulse_rate_us_per_s": rate, "settled_pulse_p2p_us": p2p}
        if settle is not None:
            per["settling_s"], metrics["settling_time_s"] = [settle] * 4, settle
        return {"table": table, "row": label, "metrics": metrics}

    results = [row("balance", "residual PPO", 1.0, [0.5, 0.7, 0.5, 0.7], 0.5, 232.4, 42.0),
               row("balance", "PID + Kalman", 0.9, [0.7, 0.5, 0.7, 0.5], 1.5, 232.0, 41.6),
               row("balance", "LQR", 1.1, [0.9, 0.9, 0.9, 0.9], 0.6, 140.0, 56.0),
               row("track circle", "residual PPO", 0.8, [0.6] * 4, None, None, None),
               row("track circle", "PID + Kalman", 0.8, [0.6] * 4, None, None, None)]  # fmt: skip
    lines = script.scorecard(results)
    assert lines[0] == "### At a glance: the residual PPO against the PID + Kalman, the LQR and the LQR → PID"
    cells = {x.split("|")[1].strip(): [c.strip() for c in x.split("|")[2:-1]] for x in lines if x.startswith("| ")
             and ":" in x.split("|")[1]}  # fmt: skip
    assert cells["balance: PID + Kalman"] == ["tie (+0%)", "worse (+0.10 mm)", "tie (+0.00 mm)", "better (-1.00 s)",
                                              "≤ (232 / 232 µs/s)", "≤ (42 / 42 µs)"]  # fmt: skip
    assert cells["balance: LQR"] == ["tie (+0%)", "better (-0.10 mm)", "better (-0.30 mm)", "better (-0.10 s)",
                                     "more (232 / 140 µs/s)", "≤ (42 / 56 µs)"]  # fmt: skip
    assert cells["track circle: PID + Kalman"] == ["tie (+0%)", "tie (+0.00 mm)", "tie (+0.00 mm)", "–", "–", "–"]
    assert "track circle: LQR" not in cells  # no LQR row on that table
    assert "In all: 4 better, 6 tie, 1 worse; the servo motion at most the other's in 3 of 4." in "\n".join(lines)
    assert script.scorecard([r for r in results if r["row"] != "residual PPO"]) == []


def results_script() -> Any:
    """``train/tools/results.py`` as a module (a script, not part of the package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("results_script", Path(__file__).resolve().parents[2] / "train"
                                                  / "tools" / "results.py")  # fmt: skip
    assert spec is not None and spec.loader is not None
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return script


def test_results_page_is_what_the_script_makes_of_results_json_and_the_intro() -> None:
    """docs/src/results.md is ``train/tools/results.py``'s page for ``docs/src/results.json`` and
    ``train/tools/results_intro.md`` as they are: an edit of the intro, or of the results, not regenerated
    (``--from-json``) fails here."""
    root = Path(__file__).resolve().parents[2]
    script = results_script()
    page = script.results_page(json.loads((root / "docs" / "src" / "results.json").read_text()))
    assert page == (root / "docs" / "src" / "results.md").read_text(), \
        "docs/src/results.md is stale: run .venv/bin/python train/tools/results.py --from-json"  # fmt: skip
    assert "| metric | shipped PPO | residual PPO | PID | PID + Kalman | LQR | LQR → PID |" in page


def test_readme_headline_is_the_results_json_table() -> None:
    """The README's headline table (between its markers) is what ``train/tools/results.py`` makes of
    ``docs/src/results.json``: no figure there goes stale when the results are regenerated; it names the
    shipped residual, the PID + Kalman and the LQR, and pairs the residual with both."""
    root = Path(__file__).resolve().parents[2]
    script = results_script()
    table = script.headline(json.loads((root / "docs" / "src" / "results.json").read_text()))
    start, end = script.README_MARKERS
    readme = (root / "README.md").read_text()
    assert readme.split(start, 1)[1].split(end, 1)[0].strip() == table.strip(), \
        "README headline is stale: run .venv/bin/python train/tools/results.py --from-json"  # fmt: skip
    assert "| residual PPO | PID + Kalman | LQR |" in table
    assert "| residual PPO − PID + Kalman |" in table and "| residual PPO − LQR |" in table


def test_environments_pushes_table_is_the_results_json_table() -> None:
    """The Environments page's pushes table (between its markers) is what ``train/tools/results.py`` makes of
    ``docs/src/results.json``, as the Control page's is: every controller on ``StewartBallDisturbance-v0`` on the
    same seeds, and the residual paired with the PID + Kalman, the LQR and the LQR → PID."""
    root = Path(__file__).resolve().parents[2]
    script = results_script()
    results = json.loads((root / "docs" / "src" / "results.json").read_text())
    table = script.pushes(results)
    start, end = script.PUSHES_MARKERS
    page = (root / "docs" / "src" / "environments.md").read_text()
    assert page.split(start, 1)[1].split(end, 1)[0].strip() == table.strip(), \
        "the Environments page's pushes table is stale: run .venv/bin/python train/tools/results.py --from-json"  # fmt: skip
    assert "| pushes, 100 seeds | shipped PPO | residual PPO | PID | PID + Kalman | LQR | LQR → PID |" in table
    for other in ("PID + Kalman", "LQR", "LQR → PID"):
        assert f"| residual PPO − {other} |" in table
    pushed = [r for r in results if r["table"] == "pushes"]
    assert {r["env"] for r in pushed} == {"StewartBallDisturbance-v0"} and len(pushed) == 6
    assert table in (root / "docs" / "src" / "results.md").read_text()


@pytest.mark.parametrize("camera", [False, True], ids=["panel", "camera"])
def test_sysid_tables_are_what_the_tool_makes_of_their_json(camera: bool) -> None:
    """The results page's sysid recovery table and camera-trims table (and the intro it is made from) are what
    ``train/tools/sysid_table.py`` makes of ``docs/src/sysid.json`` and ``sysid_camera.json``: a rerun that
    wrote one and not the other fails here."""
    import importlib.util

    root = Path(__file__).resolve().parents[2]
    spec = importlib.util.spec_from_file_location("sysid_table", root / "train" / "tools" / "sysid_table.py")
    assert spec is not None and spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    rows = json.loads((root / "docs" / "src" / ("sysid_camera.json" if camera else "sysid.json")).read_text())
    made = tool.camera_table(rows) if camera else tool.table(rows)
    start, end = tool.CAMERA_MARKERS if camera else tool.MARKERS
    for page in (root / "docs" / "src" / "results.md", root / "train" / "tools" / "results_intro.md"):
        assert page.read_text().split(start, 1)[1].split(end, 1)[0].strip() == made.strip(), \
            f"{page.name}'s table is stale: rerun train/tools/sysid_table.py"  # fmt: skip
    assert len(rows) >= 5 and made.count("\n") == len(rows) + 1


def time_to_98_tool() -> Any:
    """``train/tools/time_to_98_table.py`` as a module (it finds ``sysid_table`` beside it)."""
    import importlib.util
    import sys

    tools = str(ROOT / "train" / "tools")
    spec = importlib.util.spec_from_file_location("time_to_98_table", ROOT / "train" / "tools" / "time_to_98_table.py")
    assert spec is not None and spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(tool)
    finally:
        while tools in sys.path:
            sys.path.remove(tools)
    return tool


def test_training_time_tables_are_what_the_tool_makes_of_their_json() -> None:
    """The results page's training-time tables (and the intro it is made from), and the README's sentence on
    them, are what ``train/tools/time_to_98_table.py`` makes of ``docs/src/time_to_98.json``, which holds the
    batched balance recipe's time to ≥ 98 % for three training seeds."""
    tool = time_to_98_tool()
    runs = json.loads((ROOT / "docs" / "src" / "time_to_98.json").read_text())
    made = tool.tables(runs)
    start, end = tool.MARKERS
    for page in (ROOT / "docs" / "src" / "results.md", ROOT / "train" / "tools" / "results_intro.md"):
        assert page.read_text().split(start, 1)[1].split(end, 1)[0].strip() == made.strip(), \
            f"{page.name}'s training-time tables are stale: rerun train/tools/time_to_98_table.py"  # fmt: skip
    start, end = tool.README_MARKERS
    sentence = (ROOT / "README.md").read_text().split(start, 1)[1].split(end, 1)[0].strip()
    assert sentence == tool.readme_sentence(runs), "README's time-to-98 sentence is stale: rerun the tool"
    timed = [r for r in runs if r["env"] == "balance" and r["recipe"] == "ppo_batched" and r["budget_s"] is None]
    assert {r["seed"] for r in timed} == {0, 1, 2}  # each seed at least once
    assert made.count("| balance | `ppo_batched` |") >= 3


def test_the_readme_training_time_sentence_says_what_the_runs_show() -> None:
    """A range over the seeds, one figure where they agree, how many seeds got there where some did not, and no
    sentence at all without a run that got there."""
    tool = time_to_98_tool()

    def run(recipe: str, seed: int, wall: float | None) -> dict:
        return {"env": "balance", "recipe": recipe, "seed": seed, "wall_s": wall, "budget_s": None}

    sentence = tool.readme_sentence([run("ppo_batched", 0, 22.2), run("ppo_batched", 1, 28.8), run("ppo", 0, 90.4),
                                     run("ppo", 1, 90.0), {**run("ppo", 2, 20.0), "budget_s": 30.0}])  # fmt: skip
    assert "after 22–29 s of training on 2 cores, against 90 s for the PyBullet recipe" in sentence
    sentence = tool.readme_sentence([run("ppo_batched", 0, 25.0), run("ppo_batched", 1, None), run("ppo", 0, 80.0)])
    assert "after 25 s (1 of 2 training seeds) of training" in sentence
    with pytest.raises(ValueError, match="ppo_batched"):
        tool.readme_sentence([run("ppo_batched", 0, None), run("ppo", 0, 80.0)])


def test_a_training_time_bench_run_replaces_only_its_own_task_recipe_and_kind(tmp_path: Path) -> None:
    """A new bench output replaces the saved runs of its task, recipe and kind (time to ≥ 98 % or a budget) and
    keeps the others; a file that is not a bench output is refused before anything is written."""
    tool = time_to_98_tool()

    def bench(recipe: str, budget: float | None, seeds: list[int]) -> dict:
        runs = [{"recipe": recipe, "seed": s, "timesteps": 1000 * (s + 1), "wall_s": 1.0 + s, "evaluated_s": 2.0 + s,
                 "pybullet": 1.0, "mujoco": 0.99, "pybullet_rms_mm": 3.0, "mujoco_rms_mm": 3.1, "candidates": [],
                 "budget_s": budget} for s in seeds]  # fmt: skip
        return {"env": "balance", "cores": 2, "episodes": 100, "eval_freq": None if budget else 12500,
                "budget_s": budget, "runs": runs}  # fmt: skip

    saved = tool.runs_of([bench("ppo_batched", None, [0, 1, 2]), bench("ppo_batched", 30.0, [0, 1, 2]),
                          bench("ppo", None, [0])])  # fmt: skip
    fresh = tool.runs_of([bench("ppo_batched", None, [5])])
    got = tool.merged(saved, fresh)
    assert [(r["recipe"], r["budget_s"], r["seed"]) for r in got] == [
        ("ppo_batched", 30.0, 0), ("ppo_batched", 30.0, 1), ("ppo_batched", 30.0, 2), ("ppo", None, 0),
        ("ppo_batched", None, 5)]  # fmt: skip
    made = tool.tables(got)
    assert "| balance | `ppo_batched` | 5 | 12,500 | 6,000 | 6.0 | 7.0 | 100% / 99% |" in made
    assert "| balance | `ppo_batched` | 2 | 30 | 3,000 | 100% (3.00) | 99% (3.10) |" in made
    saved_file = ROOT / "docs" / "src" / "time_to_98.json"
    before = saved_file.read_bytes()
    (tmp_path / "bad.json").write_text("Traceback (most recent call last):\n")
    (tmp_path / "other.json").write_text('{"env": "balance"}\n')  # JSON, but no runs
    unjudged = {key: value for key, value in bench("ppo", None, [0]).items() if key != "episodes"}
    (tmp_path / "unjudged.json").write_text(json.dumps(unjudged))  # no held-out episodes
    (tmp_path / "seedless.json").write_text(json.dumps({**unjudged, "episodes": 100, "runs": [{"recipe": "ppo"}]}))
    for bad in ("bad.json", "other.json", "missing.json", "unjudged.json", "seedless.json"):
        with pytest.raises(SystemExit) as exit_info:
            tool.main([str(tmp_path / bad), "--page", str(tmp_path / "page.md")])
        assert exit_info.value.code == 2 and saved_file.read_bytes() == before
