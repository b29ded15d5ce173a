"""Where PyBullet cannot be imported (Python 3.12 and newer: it has no wheel, and the ``sim`` extra installs MuJoCo
instead), the envs, ``evaluate`` and ``demo`` run on MuJoCo, say so once, and keep their figures within the two
engines' agreement. PyBullet is blocked from import here by a package of that name that refuses to load."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

NOTE = "note: PyBullet cannot be imported here"


@pytest.fixture(scope="module")
def blocked(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """An environment for a subprocess in which ``import pybullet`` (and ``pybullet_utils``) raises ImportError."""
    stub = tmp_path_factory.mktemp("no_pybullet")
    for name in ("pybullet", "pybullet_utils"):
        (stub / name).mkdir()
        (stub / name / "__init__.py").write_text('raise ImportError("PyBullet is blocked here (a test)")\n')
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(stub), os.environ.get("PYTHONPATH", "")])}


def run(args: list[str], env: dict[str, str] | None = None, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=600, env=env, cwd=cwd)


def test_gym_make_runs_on_mujoco_and_says_so_once(blocked: dict[str, str]) -> None:
    code = ("import gymnasium as gym, numpy as np, stewart_gym\n"
            "for env_id in ('StewartBallBalance-v0', 'StewartBallTrack-v0'):\n"
            "    env = gym.make(env_id)\n"
            "    env.reset(seed=0)\n"
            "    env.step(np.zeros(2, np.float32))\n"
            "    print(type(env.unwrapped.sim).__name__)\n"
            "    env.close()\n")  # fmt: skip
    proc = run(["-c", code], env=blocked)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["MujocoSim", "MujocoSim"] and proc.stderr.count(NOTE) == 1, proc.stderr


@pytest.mark.slow
def test_evaluate_and_demo_run_on_mujoco_with_the_figures_of_the_two_engines(blocked: dict[str, str],
                                                                          tmp_path: Path) -> None:  # fmt: skip
    """``evaluate --json`` reports the engine it ran on, with the same success and an RMS error within 1 mm of
    PyBullet's on the same seeds (the engines' agreement); ``demo`` writes its table and plot (a GIF where MuJoCo
    can draw, else a note saying why)."""
    args = ["-m", "stewart_gym", "evaluate", "--policy", "pid-kalman", "--episodes", "3", "--json"]
    fallback, reference = run(args, env=blocked), run(args)
    assert fallback.returncode == 0 and reference.returncode == 0, fallback.stderr + reference.stderr
    got, ref = json.loads(fallback.stdout), json.loads(reference.stdout)
    assert (got["backend"], ref["backend"]) == ("mujoco", "pybullet") and fallback.stderr.count(NOTE) == 1
    assert got["success_rate"] == ref["success_rate"] == 1.0
    assert abs(got["rms_error_mm"] - ref["rms_error_mm"]) < 1.0, (got["rms_error_mm"], ref["rms_error_mm"])
    demo = run(["-m", "stewart_gym", "demo", "--episodes", "2", "--workers", "1", "--out", str(tmp_path / "demo")],
               env=blocked, cwd=tmp_path)  # fmt: skip
    assert demo.returncode == 0 and "(mujoco)" in demo.stdout and "Traceback" not in demo.stderr, demo.stderr
    metrics = json.loads((tmp_path / "demo" / "demo_metrics.json").read_text())
    assert all(m["success_rate"] == 1.0 for m in metrics.values()) and (tmp_path / "demo" / "demo_pulses.png").exists()
    assert (tmp_path / "demo" / "demo.gif").exists() or "note: no GIF" in demo.stderr
