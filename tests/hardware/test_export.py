"""Policy bundles: ONNX export parity with SB3 and a loader that needs no torch."""


from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from stewart_gym.calibration import ServoCalibration
from stewart_gym.hardware.export import BundlePolicy, export_pid, export_sb3

CAL = ServoCalibration.default("servo-hexapod")


PULSES = np.array([1500.0, 1400.25, 1600.5, 1100.0, 1900.0, 1234.75])


@pytest.mark.slow
def test_a_model_the_own_pass_does_not_cover_predicts_through_sb3() -> None:
    """A2C, and PPO with gSDE's squashed actions, predict through SB3's own ``predict``: the same actions, within
    the action space."""
    import gymnasium as gym
    import torch
    from stable_baselines3 import A2C, PPO

    from stewart_gym.sb3_models import SB3Policy

    obs = np.random.default_rng(1).normal(0, 1, (64, 3)).astype(np.float32)
    for model in (A2C("MlpPolicy", gym.make("Pendulum-v1"), device="cpu", seed=0),
                  PPO("MlpPolicy", gym.make("Pendulum-v1"), device="cpu", seed=0, use_sde=True,
                      policy_kwargs={"squash_output": True})):  # fmt: skip
        with torch.no_grad():
            model.policy.action_net.weight.mul_(300.0)  # (far outside ±1 before the squashing)
        policy = SB3Policy(model)
        assert not policy.own_pass
        got = policy.predict(obs)[0]
        assert np.array_equal(got, model.predict(obs, deterministic=True)[0]) and np.abs(got).max() <= 2.0


def test_export_parity_with_sb3_predict(tmp_path: Path) -> None:
    """Bundle (onnxruntime + numpy) vs SB3 predict(deterministic=True) on 1,000 observations, for PPO, SAC, TD3
    and TQC; each model loads back as the algorithm that trained it."""
    import gymnasium as gym
    from sb3_contrib import TQC
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from stewart_gym.sb3_models import load_sb3

    obs = np.random.default_rng(0).normal(0, 1, (1000, 12)).astype(np.float32)
    for algo in (PPO, SAC, TD3, TQC):
        venv = VecNormalize(DummyVecEnv([lambda: gym.make("StewartBallBalance-v0")]))
        kwargs = {"n_steps": 64, "batch_size": 32} if algo is PPO else {"learning_starts": 10, "buffer_size": 500}
        model = algo("MlpPolicy", venv, policy_kwargs={"net_arch": [32, 32]}, device="cpu", seed=0, **kwargs)
        model.set_logger(Logger(folder=None, output_formats=[]))  # no empty tempdir/SB3-<time> folder
        model.learn(100)
        folder = tmp_path / algo.__name__
        folder.mkdir()
        model.save(folder / "model.zip")
        venv.save(str(folder / "vecnormalize.pkl"))
        venv.close()
        bundle = BundlePolicy(export_sb3(folder, tmp_path / f"{algo.__name__}_bundle"))
        reference = load_sb3(folder)
        assert type(reference.model) is algo
        expected = reference.predict(obs, deterministic=True)[0]
        # SB3Policy's own deterministic pass is SB3's predict to the last bit, for rows and for one observation,
        # and the policy still pickles after it
        assert np.array_equal(expected, reference.model.predict(reference.normalize(obs), deterministic=True)[0])
        one = reference.predict(obs[7], deterministic=True)[0]
        sb3_one = reference.model.predict(reference.normalize(obs[7]), deterministic=True)[0]
        assert one.shape == (2,) and np.array_equal(one, sb3_one), algo.__name__
        assert np.array_equal(pickle.loads(pickle.dumps(reference)).predict(obs)[0], expected)
        with pytest.raises(ValueError, match=r"shape \(12,\)"):
            reference.predict(obs[:, :5])
        assert reference.own_pass, algo.__name__
        got = bundle(obs)
        assert np.abs(got - expected).max() <= 1e-5, algo.__name__
        assert not list((tmp_path / f"{algo.__name__}_bundle").glob("*.pkl"))  # no pickle in the bundle


def test_a_bundle_is_its_two_files(tmp_path: Path) -> None:
    """An exported network's bundle is ``bundle.json`` and ``policy.onnx`` alone (the weights inside the ONNX
    file, none in a ``policy.onnx.data`` beside it, even where an earlier export left one): a folder holding a
    copy of just those two files acts as the original, and ``export --policy BUNDLE`` copies a working bundle, its
    ``policy.onnx.data`` too where it has one."""
    import gymnasium as gym
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from stewart_gym.cli import main

    venv = VecNormalize(DummyVecEnv([lambda: gym.make("StewartBallBalance-v0", backend="batched")]))
    model = PPO("MlpPolicy", venv, policy_kwargs={"net_arch": [16, 16]}, device="cpu", seed=0)
    run = tmp_path / "run"
    run.mkdir()
    model.save(run / "model.zip")
    venv.save(str(run / "vecnormalize.pkl"))
    venv.close()
    out = tmp_path / "bundle"
    out.mkdir()
    (out / "policy.onnx.data").write_bytes(b"stale")
    export_sb3(run, out)
    assert sorted(p.name for p in out.iterdir()) == ["bundle.json", "policy.onnx"]
    copied = tmp_path / "copied"
    copied.mkdir()
    for name in ("bundle.json", "policy.onnx"):
        (copied / name).write_bytes((out / name).read_bytes())
    obs = np.random.default_rng(0).normal(0, 1, (50, 12)).astype(np.float32)
    np.testing.assert_array_equal(BundlePolicy(copied)(obs), BundlePolicy(out)(obs))
    assert main(["export", "--policy", str(copied), "--out", str(tmp_path / "again")]) == 0
    np.testing.assert_array_equal(BundlePolicy(tmp_path / "again")(obs), BundlePolicy(out)(obs))
    # a bundle whose weights lie beside its graph, as torch's exporter wrote them before: copied with them
    import onnx

    apart = tmp_path / "apart"
    apart.mkdir()
    (apart / "bundle.json").write_bytes((out / "bundle.json").read_bytes())
    onnx.save_model(onnx.load(str(out / "policy.onnx")), str(apart / "policy.onnx"), save_as_external_data=True,
                    location="policy.onnx.data", size_threshold=0)  # fmt: skip
    assert main(["export", "--policy", str(apart), "--out", str(tmp_path / "apart_copy")]) == 0
    assert (tmp_path / "apart_copy" / "policy.onnx.data").is_file()
    np.testing.assert_array_equal(BundlePolicy(tmp_path / "apart_copy")(obs), BundlePolicy(out)(obs))


def test_bundle_loader_needs_no_torch(tmp_path: Path) -> None:
    """The deployment side imports onnxruntime and numpy only."""
    import subprocess
    import sys

    bundle = export_pid(Path(__file__).resolve().parents[2] / "stewart_gym/policies/pid_gains.json", tmp_path / "b")
    code = ("import sys; sys.modules['torch'] = None\n"  # importing torch now fails
            "from stewart_gym.hardware.export import BundlePolicy\n"
            f"import numpy as np; p = BundlePolicy({str(bundle)!r}); print(p(np.zeros(12)).shape)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "(2,)" in out.stdout


def test_export_pid_keeps_the_observer_its_gains_name(tmp_path: Path) -> None:
    """Gains that name their observer (``pid_kalman_gains.json``: ``kalman``) export behind it; gains that name
    none, behind the low-pass one; the bundle's gains are the checked gains, without the ``estimator`` field."""
    policies = Path(__file__).resolve().parents[2] / "stewart_gym/policies"
    kalman = json.loads((export_pid(policies / "pid_kalman_gains.json", tmp_path / "k") / "bundle.json").read_text())
    plain = json.loads((export_pid(policies / "pid_gains.json", tmp_path / "p") / "bundle.json").read_text())
    assert (kalman["estimator"], plain["estimator"]) == ("kalman", "lowpass")
    assert "estimator" not in kalman["gains"] and kalman["gains"]["kp_pos"] == 2.0


def test_export_keeps_a_bundle_unless_told_to_replace_it_and_replaces_it_whole(tmp_path: Path, capfd) -> None:
    """export into a folder that holds a bundle: one error line and the bundle as it was; with --overwrite the
    new bundle replaces it whole (a PID over a network: no policy.onnx left beside the PID's gains); a new bundle
    that cannot be made leaves the old one, and a refused export into a new folder leaves no folder."""
    from tests.conftest import cli

    out = tmp_path / "b"
    assert cli(capfd, "export", "--policy", "shipped", "--out", str(out))[0] == 0
    before = {name: (out / name).read_bytes() for name in ("bundle.json", "policy.onnx")}
    code, _, err = cli(capfd, "export", "--policy", "pid", "--out", str(out))
    assert code == 1 and err.startswith("error: ") and "--overwrite" in err and err.count("\n") == 1, err
    assert {name: (out / name).read_bytes() for name in before} == before
    broken = tmp_path / "broken"  # a bundle whose network does not load: found while the new bundle is made
    assert cli(capfd, "export", "--policy", "shipped", "--out", str(broken))[0] == 0
    (broken / "policy.onnx").write_bytes(b"garbage")
    code, _, err = cli(capfd, "export", "--policy", str(broken), "--out", str(out), "--overwrite")
    assert code == 1 and "not a loadable ONNX model" in err
    assert {name: (out / name).read_bytes() for name in before} == before
    assert sorted(p.name for p in out.iterdir()) == ["bundle.json", "policy.onnx"]  # no half-made bundle
    (out / ".export-left").mkdir()  # where an export killed midway made its bundle (a folder it cannot write beside)
    assert cli(capfd, "export", "--policy", "pid", "--out", str(out), "--overwrite")[0] == 0
    assert sorted(p.name for p in out.iterdir()) == ["bundle.json"]  # (that folder gone too)
    assert json.loads((out / "bundle.json").read_text())["kind"] == "pid"
    assert BundlePolicy(out).kind == "pid"
    assert cli(capfd, "export", "--policy", str(broken), "--out", str(tmp_path / "new" / "c"))[0] == 1
    assert not (tmp_path / "new").exists()


@pytest.mark.slow
def test_an_export_over_a_bundle_never_shows_half_of_each_and_a_killed_one_blocks_nothing(tmp_path: Path,
                                                                                        capfd) -> None:  # fmt: skip
    """export --overwrite of a network over a PID's bundle, in its own process: while it runs, the folder holds the
    old bundle (never a network beside the PID's bundle.json), then the new one. An export killed (SIGKILL) once it
    has begun leaves the old bundle, and the next export --overwrite works."""
    import subprocess
    import sys
    import time

    from tests.conftest import cli

    out = tmp_path / "b"

    def export(*extra: str) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "stewart_gym", "export", "--policy", "shipped", "--out",
                                 str(out), "--overwrite", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    assert cli(capfd, "export", "--policy", "pid", "--out", str(out))[0] == 0
    old = (out / "bundle.json").read_bytes()
    proc, mixed = export(), 0
    while proc.poll() is None:
        if (out / "policy.onnx").exists() and (out / "bundle.json").read_bytes() == old:
            mixed += 1
        time.sleep(0.002)
    assert proc.returncode == 0 and mixed == 0, proc.stderr.read()
    assert json.loads((out / "bundle.json").read_text())["kind"] == "onnx" and (out / "policy.onnx").is_file()
    assert not list(tmp_path.glob(".*export-*"))  # the folder it was made in is gone

    assert cli(capfd, "export", "--policy", "pid", "--out", str(out), "--overwrite")[0] == 0
    old = (out / "bundle.json").read_bytes()
    proc = export()
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".export-b-*")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    proc.kill()
    proc.wait()
    assert (out / "bundle.json").read_bytes() == old and sorted(p.name for p in out.iterdir()) == ["bundle.json"]
    assert cli(capfd, "export", "--policy", "shipped", "--out", str(out), "--overwrite")[0] == 0
    assert sorted(p.name for p in out.iterdir()) == ["bundle.json", "policy.onnx"]
