"""``make demo`` installs the ``demo`` extra only, without torch and Stable-Baselines3: the shipped learned policies
run as their ONNX bundles there (said once), with the figures of the trained networks. Torch is blocked from
import here by packages of those names that refuse to load, as in a venv that lacks them. ``demo`` itself runs
in such a venv in ``tests/test_install.py``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import sg_in

NOTE = "note: torch is not installed here: the shipped learned policies run as their ONNX bundles"


@pytest.fixture(scope="module")
def blocked(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """An environment for a subprocess in which ``import torch`` and ``import stable_baselines3`` raise."""
    stub = tmp_path_factory.mktemp("no_torch")
    for name in ("torch", "stable_baselines3", "sb3_contrib"):
        (stub / name).mkdir()
        (stub / name / "__init__.py").write_text(f"raise ModuleNotFoundError(\"No module named '{name}' (blocked here: a "
                                                 f"test)\", name={name!r})\n")  # what a venv without it raises
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(stub), os.environ.get("PYTHONPATH", "")])}


def run(args: list[str], env: dict[str, str] | None = None, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stewart_gym", *args], capture_output=True, text=True, timeout=600,
                          env=env, cwd=cwd)  # fmt: skip


@pytest.mark.parametrize("policy", ["shipped", "shipped-residual"])
def test_evaluate_runs_a_shipped_policy_as_its_bundle_with_the_networks_figures(
        blocked: dict[str, str], policy: str, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    args = ["evaluate", "--policy", policy, "--episodes", "2", "--json"]
    bundle, network = run(args, env=blocked), sg_in(capfd, *args)  # the network: here, where torch is
    assert bundle.returncode == 0 and network.returncode == 0, bundle.stderr + network.stderr
    assert bundle.stderr.count(NOTE) == 1 and NOTE not in network.stderr, bundle.stderr
    got, ref = json.loads(bundle.stdout), json.loads(network.stdout)
    assert got["success_rate"] == ref["success_rate"] == 1.0
    assert abs(got["rms_error_mm"] - ref["rms_error_mm"]) < 0.05, (got["rms_error_mm"], ref["rms_error_mm"])


def test_a_trained_model_without_torch_is_one_line_naming_the_extra(blocked: dict[str, str], tmp_path: Path) -> None:
    """A run folder (no bundle beside it) needs torch: ``error:`` naming the train extra, no traceback."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    for name in ("model.zip", "config.yaml", "vecnormalize.pkl"):
        (run_dir / name).write_bytes((Path(__file__).resolve().parents[1] / "stewart_gym" / "policies" / "balance"
                                      / name).read_bytes())  # fmt: skip
    proc = run(["evaluate", "--policy", str(run_dir), "--episodes", "1"], env=blocked)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("error: ") and "stewart_gym[train]" in proc.stderr
