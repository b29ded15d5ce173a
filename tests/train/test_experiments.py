"""The experiments of ``train/experiments/`` the Control page reports: each trains through its ``run(argv)`` (one,
``memory``, as a user runs it: ``python -m train.experiments.NAME`` from the repository's root), and refuses bad
options in one line before any work, as a user runs it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def experiment(name: str) -> list[str]:
    """The command that runs ``train/experiments/<name>.py`` as a user runs it, from the repository's root (``cwd``
    :data:`ROOT`): ``python -m train.experiments.<name>``."""
    import sys

    return [sys.executable, "-m", f"train.experiments.{name}"]


def run_experiment(name: str, args: list[str], out: Path, *, as_user: bool = False) -> dict:
    """``train.experiments.<name>.run(ARGS + ["--out", OUT])`` in this process (its imports are made already), or
    with ``as_user`` ``python -m train.experiments.<name> ARGS --out OUT`` as a user runs it (exit 0); the JSON
    line it wrote."""
    import subprocess

    if as_user:
        proc = subprocess.run([*experiment(name), *args, "--out", str(out)], capture_output=True, text=True,
                              timeout=600, cwd=ROOT)  # fmt: skip
        assert proc.returncode == 0, proc.stderr[-2000:]
    else:
        import importlib
        import sys

        sys.path.insert(0, str(ROOT))  # the repository's root, as `python -m train.experiments.…` has it
        try:
            importlib.import_module(f"train.experiments.{name}").run([*args, "--out", str(out)])
        finally:
            sys.path.remove(str(ROOT))
    return json.loads(out.read_text())


@pytest.mark.slow
def test_memory_experiment_trains_and_evaluates_a_stacked_policy(tmp_path: Path) -> None:
    """``train/experiments/memory.py --stack 2`` for one PPO rollout: exits 0 and reports the Control page's
    metrics for the stacked policy (evaluated through the shared evaluation code); a bad size is refused."""
    import subprocess

    script = experiment("memory")
    result = run_experiment("memory", ["--stack", "2", "--steps", "256", "--episodes", "1"], tmp_path / "m.json",
                            as_user=True)  # fmt: skip
    assert result["stack"] == 2 and result["steps"] == 256 and 0.0 <= result["success_rate"] <= 1.0
    assert result["rms_error_mm"] > 0 and "settled_pulse_p2p_us" in result and "settling_time_s" in result
    bad = subprocess.run([*script, "--stack", "0"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert bad.returncode == 2 and "error:" in bad.stderr and "--stack" in bad.stderr


@pytest.mark.slow
def test_curriculum_experiment_changes_the_training_envs_between_rollouts(tmp_path: Path) -> None:
    """``train/experiments/curriculum.py`` for two PPO rollouts (2 × 2,048 steps): exits 0, reports the Control
    page's metrics, and the curriculum set the training envs before each rollout (``train(callbacks=...)``):
    the start box at 10 % of its 2/3 of the half plate, then, half-way, at 85 %; the reward's near-target scale
    from the task's 15 mm to 10 mm. Bad options, a run folder it cannot make and an ``--out`` with no folder are
    one ``error:`` line, exit 2, before any training."""
    import subprocess

    script = experiment("curriculum")
    expected = {"start": [2 / 3 * 0.1, 2 / 3 * 0.85], "precision": [0.015, 0.010], "none": []}
    for kind, seen in expected.items():
        result = run_experiment("curriculum", ["--curriculum", kind, "--steps", "4096", "--episodes", "1"],
                                tmp_path / f"{kind}.json")  # fmt: skip
        assert result["curriculum"] == kind and result["steps"] == 4096 and 0.0 <= result["success_rate"] <= 1.0
        assert result["rms_error_mm"] > 0 and "settled_pulse_p2p_us" in result and "settling_time_s" in result
        assert result["difficulty_first_last"] == pytest.approx(seen, abs=1e-4), kind
    (tmp_path / "a_file").write_text("")
    for bad in (["--curriculum", "wind"], ["--curriculum", "start", "--steps", "0"],  # refused before training:
                ["--curriculum", "start", "--run-dir", str(tmp_path / "a_file" / "run")],  # a run folder it can't make
                ["--curriculum", "start", "--out", str(tmp_path / "missing" / "c.json")]):  # nowhere to write  # fmt: skip
        proc = subprocess.run([*script, *bad], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert proc.returncode == 2 and "error:" in proc.stderr and "Traceback" not in proc.stderr, bad


@pytest.mark.slow
def test_action_filter_experiment_filters_in_training_and_in_evaluation(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """``train/experiments/action_filter.py``: the wrapper (training) and the evaluation policy apply the same
    low-pass y ← y + α (a − y), starting from 0 each episode; one PPO rollout exits 0 with the Control page's
    metrics; a bad ``--alpha`` is one ``error:`` line, exit 2."""
    import importlib
    import subprocess

    import gymnasium as gym

    script = experiment("action_filter")
    monkeypatch.syspath_prepend(str(ROOT))  # the repository's root, as `python -m train.experiments.…` has it
    module = importlib.import_module("train.experiments.action_filter")

    class Constant:  # a model whose action is always 1 (or 2: clipped to the action space)
        def __init__(self, value: float) -> None:
            self.value = value

        def predict(self, x: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
            return np.full((1, 2), self.value, dtype=np.float32), None

    class Unnormalized:
        def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
            return obs

    policy = module.FilteredPolicy(Constant(2.0), Unnormalized(), 0.5)
    got = [float(policy.predict(np.zeros(12), None, np.array([i == 0 or i == 3]))[0][0, 0]) for i in range(5)]
    assert got == pytest.approx([0.5, 0.75, 0.875, 0.5, 0.75])
    env = module.ActionLowPass(gym.make("StewartBallBalance-v0"), 0.5)
    env.reset(seed=0)
    sent = [env.action(np.ones(2, dtype=np.float32))[0] for _ in range(3)]
    env.reset(seed=1)
    assert sent == pytest.approx([0.5, 0.75, 0.875]) and env.action(np.ones(2, dtype=np.float32))[0] == 0.5
    _, _, _, _, info = env.step(np.ones(2, dtype=np.float32))  # the env is sent the filtered tilt
    assert info["commanded_tilt_rad"] == pytest.approx(env.unwrapped.mapper(np.full(2, 0.75, np.float32)).pose[3:5])
    env.close()
    result = run_experiment("action_filter", ["--alpha", "0.5", "--steps", "256", "--episodes", "1"],
                            tmp_path / "f.json")  # fmt: skip
    assert result["alpha"] == 0.5 and result["steps"] == 256 and 0.0 <= result["success_rate"] <= 1.0
    assert result["rms_error_mm"] > 0 and "settled_pulse_p2p_us" in result
    for bad in ("0", "1.5", "nan"):
        proc = subprocess.run([*script, "--alpha", bad], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert proc.returncode == 2 and "error:" in proc.stderr and "--alpha" in proc.stderr, bad


@pytest.mark.slow
def test_distill_experiment_clones_the_lqr_pid_and_evaluates_the_network(tmp_path: Path) -> None:
    """``train/experiments/distill.py`` with 3 teacher episodes and one DAgger round: exits 0 and reports the
    Control page's metrics for the network, with every step of the teacher's 3 full episodes and of the DAgger
    episode (which the student may end early) as data; bad options are one ``error:`` line, exit 2."""
    import subprocess

    script = experiment("distill")
    result = run_experiment("distill", ["--bc-episodes", "3", "--dagger", "0", "--dagger-episodes", "1",
                                                   "--episodes", "2"], tmp_path / "d.json")  # fmt: skip
    assert result["bc_episodes"] == 3 and result["dagger"] == [0.0] and 1500 < result["samples"] <= 2000
    assert 0.0 <= result["success_rate"] <= 1.0 and result["rms_error_mm"] > 0 and result["final_loss"] >= 0
    assert "settled_pulse_p2p_us" in result and "settling_time_s" in result
    for bad in (["--dagger", "0.5,2"], ["--dagger", "x"], ["--episodes", "0"]):
        proc = subprocess.run([*script, *bad], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert proc.returncode == 2 and proc.stderr.startswith("error:") and "Traceback" not in proc.stderr, bad


def test_settling_bound_prints_a_bound_per_start_and_refuses_bad_sizes() -> None:
    """``train/experiments/settling_bound.py``: a row per start angle and the mean; the diagonal starts (both axes at full
    tilt) settle sooner than the axis-aligned ones; impossible sizes are refused with one ``error:`` line."""
    import subprocess

    script = experiment("settling_bound")
    proc = subprocess.run([*script, "--episodes", "8"], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = {float(line.split("|")[1]): float(line.split("|")[2]) for line in proc.stdout.splitlines()
            if line.startswith("| ") and line[2].isdigit()}  # fmt: skip
    assert sorted(rows) == [0, 45, 90, 135, 180, 225, 270, 315]
    assert all(0.3 < t < 0.6 for t in rows.values()) and rows[45] < rows[0], rows
    mean = float(proc.stdout.split("mean bound ")[1].split(" s over 8 starts")[0])
    assert mean == pytest.approx(sum(rows.values()) / 8, abs=0.006), (mean, rows)
    for args, says in ((["--episodes", "0"], "--episodes"), (["--radius-mm", "200"], "--radius-mm"),
                       (["--max-tilt-deg", "nan"], "--max-tilt-deg")):  # fmt: skip
        bad = subprocess.run([*script, *args], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert bad.returncode == 2 and "error:" in bad.stderr and says in bad.stderr, bad.stderr
        assert "Traceback" not in bad.stderr


@pytest.mark.slow
def test_hold_headroom_scales_one_gain_and_bounds_what_adapting_it_buys() -> None:
    """``train/experiments/hold_headroom.py``: a row per gain scale, the shipped row equal to ``stewart-gym evaluate --policy
    pid-kalman`` on the same seeds, every episode in one noise bin and one dead-band bin, and the hindsight pick
    (each episode's best scale) no looser than the shipped gains; bad scales are refused with one ``error:`` line."""
    import subprocess
    import sys

    script = experiment("hold_headroom")
    proc = subprocess.run([*script, "--episodes", "3", "--scales", "1.0", "1.3"], capture_output=True, text=True,
                          timeout=600, cwd=ROOT)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]] for line in proc.stdout.splitlines()
            if line.startswith("| ×")}  # fmt: skip
    assert set(rows) == {"×1", "×1.3"}, proc.stdout
    cli = subprocess.run([sys.executable, "-m", "stewart_gym", "evaluate", "--policy", "pid-kalman", "--episodes", "3",
                          "--json"], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert cli.returncode == 0, cli.stderr[-2000:]
    shipped = json.loads(cli.stdout)
    assert float(rows["×1"][1]) == pytest.approx(shipped["rms_error_mm"], abs=6e-4), (rows, shipped)
    assert float(rows["×1"][2]) == pytest.approx(shipped["final_error_mm"], abs=6e-4), (rows, shipped)
    bins = [line.split("|") for line in proc.stdout.splitlines() if line.startswith("| ") and line[2].isdigit()]
    assert sum(int(b[2]) for b in bins) == 6, proc.stdout  # 3 episodes in the noise bins, 3 in the dead-band bins
    reference = float(rows["×1"][1])
    hindsight = float(proc.stdout.split("hindsight (each episode's lowest RMS over the scales): RMS ")[1].split(" mm")[0])
    assert hindsight <= reference + 1e-3, proc.stdout
    for args, says in ((["--scales", "1.2", "1.4"], "1.0"), (["--scales", "nan", "1.0"], "--scales"),
                       (["--episodes", "0"], "--episodes")):  # fmt: skip
        bad = subprocess.run([*script, *args], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert bad.returncode == 2 and "error:" in bad.stderr and says in bad.stderr, bad.stderr
        assert "Traceback" not in bad.stderr


def test_every_experiment_is_a_module_with_run() -> None:
    """Each experiment imports as ``train.experiments.NAME`` and offers ``run(argv)``, as ``examples/`` scripts offer
    theirs: usable from Python, not only from the command line."""
    import importlib
    import inspect
    import sys

    sys.path.insert(0, str(ROOT))
    try:
        names = sorted(p.stem for p in (ROOT / "train" / "experiments").glob("*.py") if p.stem not in ("__init__", "common"))
        assert names == ["action_filter", "curriculum", "distill", "hold_headroom", "memory", "settling_bound"]
        for name in names:
            run = importlib.import_module(f"train.experiments.{name}").run
            assert list(inspect.signature(run).parameters) == ["argv"]
    finally:
        sys.path.remove(str(ROOT))
