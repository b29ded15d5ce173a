"""The evaluations during training (:mod:`stewart_gym.training_evals`): in a second process they give what they
give in the training's own, a failing or orphaned worker does not hang or linger."""

from __future__ import annotations

import csv
import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from stewart_gym.cli import main
from stewart_gym.training_evals import BackgroundEvaluator, worker_start_method

ROOT = Path(__file__).resolve().parents[1]


def train_run(run: Path, background: bool) -> None:
    assert main(["train", "--hyperparams", "ppo_batched", "--seed", "3", "--run-dir", str(run), "--timesteps", "8192",
                 "--eval-freq", "4096", "--eval-episodes", "6", "--no-progress", "--no-tensorboard",
                 "--background-eval" if background else "--no-background-eval"]) == 0  # fmt: skip


def weights(path: Path) -> dict[str, torch.Tensor]:
    return PPO.load(path, device="cpu").policy.state_dict()


def test_background_evaluations_equal_those_in_process(tmp_path: Path) -> None:
    """The same learning curve (but for its wall times), evaluations file, best model and final model."""
    train_run(tmp_path / "here", background=False)
    train_run(tmp_path / "there", background=True)
    rows = {}
    for name in ("here", "there"):
        with (tmp_path / name / "eval.csv").open() as fh:
            rows[name] = [(r["timesteps"], r["mean_reward"], r["success_rate"]) for r in csv.DictReader(fh)]
    assert [r[0] for r in rows["here"]] == ["4096", "8192"]
    assert rows["here"] == rows["there"]
    here, there = (np.load(tmp_path / name / "eval" / "evaluations.npz") for name in ("here", "there"))
    assert sorted(here.files) == sorted(there.files) and "successes" in here.files
    for key in here.files:
        np.testing.assert_array_equal(here[key], there[key])
    for model in ("best/best_model.zip", "model.zip"):
        a, b = weights(tmp_path / "here" / model), weights(tmp_path / "there" / model)
        assert all(torch.equal(a[k], b[k]) for k in a)
    assert (tmp_path / "there" / "best" / "vecnormalize.pkl").is_file()


def _broken_env() -> None:
    raise ValueError("no such platform")


def test_workers_are_spawned_where_the_temporary_directory_is_too_long_for_a_forkserver_socket(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """A forkserver listens on a Unix socket in ``$TMPDIR`` (at most 107 bytes of path, ``pymp-…/listener-…``
    taking 32): under a longer temporary directory the workers are spawned ("AF_UNIX path too long" otherwise),
    under a short one they come from the forkserver."""
    import tempfile

    long = tmp_path / ("t" * max(1, 110 - len(str(tmp_path))))
    long.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(long))
    assert worker_start_method() == "spawn"
    monkeypatch.setattr(tempfile, "tempdir", "/tmp")
    assert worker_start_method() == "forkserver"


def test_a_failing_worker_is_an_error_not_a_hang() -> None:
    evaluator = BackgroundEvaluator(_broken_env, PPO, 2)
    model = PPO("MlpPolicy", "Pendulum-v1", n_steps=64, device="cpu")
    try:
        zipped = io.BytesIO()
        model.save(zipped)
        evaluator.submit(64, model, zipped.getvalue())
        with pytest.raises(RuntimeError, match="the evaluation process failed: ValueError: no such platform"):
            evaluator.results(wait=True)
    finally:
        evaluator.close()


ORPHAN = """
import functools, sys, time
from stable_baselines3 import PPO
from stewart_gym.training import evaluation_env
from stewart_gym.training_evals import BackgroundEvaluator, worker_start_method
evaluator = BackgroundEvaluator(functools.partial(evaluation_env, "StewartBallBalance-v0", 2, 0, {"backend": "batched"}),
                                PPO, 2)
evaluator.start()
print(evaluator.pid, flush=True)
time.sleep(600)
"""


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def test_the_worker_ends_when_the_training_process_is_killed() -> None:
    """A training killed outright (SIGKILL: no clean-up runs) leaves no evaluation worker behind."""
    proc = subprocess.Popen([sys.executable, "-c", ORPHAN], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        worker = int(proc.stdout.readline())
        assert not _gone(worker)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.monotonic() + 15
        while not _gone(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _gone(worker)
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stopped_training_exits_and_leaves_no_worker(sig: signal.Signals, tmp_path: Path) -> None:
    """Ctrl-C (to the whole process group, as a terminal sends it) or SIGTERM (to the training alone) while the
    worker evaluates or waits: one error line, the signal's exit status, and no process of the group left, even
    with a snapshot the worker never read."""
    run = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "stewart_gym", "train", "--hyperparams", "ppo_batched",
                             "--run-dir", str(run), "--timesteps", "400000", "--eval-freq", "4096", "--no-progress",
                             "--no-tensorboard", "--background-eval"], cwd=ROOT, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (run / "eval.csv").is_file() or len(
                (run / "eval.csv").read_text().splitlines()) < 2:  # fmt: skip
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.2)
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 128 + sig, err[-3000:]  # what the training said, if it ended otherwise
        assert err.strip().splitlines()[-1].startswith("error: stopped by")
        deadline = time.monotonic() + 10
        while (left := subprocess.run(["pgrep", "-a", "-g", str(proc.pid)], capture_output=True,
                                      text=True).stdout.strip()) and time.monotonic() < deadline:  # fmt: skip
            time.sleep(0.2)
        assert left == ""
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
