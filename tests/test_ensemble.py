"""Ensembles: several networks of one recipe, trained with different seeds, acting with the mean of their actions.

``stewart-gym ensemble`` writes the folder; ``--policy`` runs it (evaluate, export, deploy) like a run folder; its
bundle's one ONNX graph holds every network with its own normalisation. The shipped balance residual is one.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import sg_in

from stewart_gym.hardware.export import BundlePolicy
from stewart_gym.outputs import ensemble_members
from stewart_gym.registry import POLICY_DIR, deployable_policy, load_policy, resolve_policy
from stewart_gym.sb3_models import check_residual
from stewart_gym.training import load_hyperparams

ROOT = Path(__file__).resolve().parents[1]
RESIDUAL = POLICY_DIR / "balance_residual"


def observations(n: int, seed: int) -> np.ndarray:
    """Observations with the ball 0–75 mm from the target: far enough that the residual's correction acts."""
    rng = np.random.default_rng(seed)
    obs = rng.uniform(-0.2, 0.2, (n, 12)).astype(np.float32)
    obs[:, 0:2] = obs[:, 4:6] + rng.uniform(-0.5, 0.5, (n, 2))
    return obs


@pytest.mark.parametrize(("env_id", "folder", "base", "gamma"), [
    ("StewartBallBalance-v0", RESIDUAL, "lqr-pid", 0.995),
    ("StewartBallTrack-v0", POLICY_DIR / "track_residual", "lqr-pid", 0.98),
])  # fmt: skip
def test_the_shipped_residuals_are_six_networks_of_the_shipped_recipe_averaged(env_id: str, folder: Path, base: str,
                                                                                gamma: float) -> None:  # fmt: skip
    """Six members, seeds 0–5, each trained with the env's section of ppo_residual.yml as it is now, over the
    base as shipped now (each run's recorded residual, read as a recorded one, is the recipe's: a retune of the
    shipped controller that the networks were not trained over fails here); the correction is the mean of
    theirs (and differs from every one of them); the bundle sends the same sum."""
    source = resolve_policy("shipped-residual", env_id=env_id)
    assert source.kind == "ensemble" and source.path == folder
    recipe = load_hyperparams("ppo", env_id, "ppo_residual")
    configs = [yaml.safe_load((m / "config.yaml").read_text()) for m in ensemble_members(folder)]
    assert sorted(c["options"]["seed"] for c in configs) == [0, 1, 2, 3, 4, 5]
    for config in configs:
        assert config["options"]["env_id"] == env_id
        trained = {k: v for k, v in config["hyperparams"].items() if k in recipe}
        assert trained["gamma"] == gamma and trained["residual"]["base"] == base
        assert {k: v for k, v in trained.items() if k != "residual"} == {k: v for k, v in recipe.items()
                                                                          if k != "residual"}  # fmt: skip
        assert check_residual(trained["residual"], recorded=True) == check_residual(recipe["residual"])
    policy = load_policy(source)
    obs = observations(64, 0)
    members = np.stack([m.predict(obs)[0] for m in policy.learned.members])
    mean = policy.learned.predict(obs)[0]
    np.testing.assert_allclose(mean, members.mean(axis=0), atol=1e-6)
    assert min(np.abs(mean - m).max() for m in members) > 1e-2
    bundle = deployable_policy(source)
    assert bundle.meta["ensemble"] == 6 and bundle.meta["obs_mean"] is None
    for k, o in enumerate(observations(40, 1)):
        start = np.array([k == 0])
        np.testing.assert_allclose(bundle.predict(o, episode_start=start)[0],
                                   policy.predict(o, episode_start=start)[0], atol=1e-4)  # fmt: skip


@pytest.mark.slow
def test_an_ensemble_made_on_the_command_line_evaluates_and_exports_as_the_mean(
        tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """``stewart-gym ensemble`` of two run folders: ``evaluate`` and ``export`` take the folder, the bundle's graph
    gives the mean of the two networks' corrections (each normalised with its own statistics), and the policy
    deploy runs from the bundle sends what the folder's policy does."""
    runs = [str(m) for m in ensemble_members(RESIDUAL)[:2]]
    made = sg_in(capfd, "ensemble", *runs, "--out", "pair", "--note", "two of the shipped six", cwd=tmp_path)
    assert made.returncode == 0, made.stderr[-2000:]
    assert "ensemble of 2 networks written to pair" in made.stdout
    index = json.loads((tmp_path / "pair" / "ensemble.json").read_text())
    assert index["members"] == ["members/0", "members/1"] and index["note"] == "two of the shipped six"
    evaluated = sg_in(capfd, "evaluate", "--policy", "pair", "--episodes", "2", "--json", cwd=tmp_path)
    assert evaluated.returncode == 0, evaluated.stderr[-2000:]
    assert 0.0 <= json.loads(evaluated.stdout)["success_rate"] <= 1.0
    exported = sg_in(capfd, "export", "--policy", "pair", "--out", "bundle", cwd=tmp_path)
    assert exported.returncode == 0, exported.stderr[-2000:]
    pair, bundle = load_policy(str(tmp_path / "pair")), BundlePolicy(tmp_path / "bundle")
    singles = [load_policy(r) for r in runs]
    obs = observations(200, 2)
    correction = pair.learned.predict(obs)[0]
    np.testing.assert_allclose(correction, np.mean([s.learned.predict(obs)[0] for s in singles], axis=0), atol=1e-6)
    import onnxruntime as ort

    graph = ort.InferenceSession(str(tmp_path / "bundle" / "policy.onnx"), providers=["CPUExecutionProvider"])
    np.testing.assert_allclose(graph.run(None, {"obs": obs})[0], correction, atol=1e-4)  # the mean correction
    deployed = deployable_policy(resolve_policy(str(tmp_path / "bundle")))  # what deploy runs
    for k, o in enumerate(obs[:40]):
        start = np.array([k == 0])
        np.testing.assert_allclose(deployed.predict(o, episode_start=start)[0], pair.predict(o, episode_start=start)[0],
                                   atol=1e-4)  # fmt: skip
    assert bundle.meta["ensemble"] == 2


@pytest.mark.slow
def test_networks_trained_unalike_or_an_existing_folder_are_one_error_line_and_nothing_is_written(
        tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """The shipped balance network (no residual base) and a residual member cannot be averaged; an
    ensemble is not written over a folder that holds files; one network, or one network twice (also as a copied
    run folder), is not an ensemble; a file that is no model is named as such."""
    member = str(ensemble_members(RESIDUAL)[0])
    bare = tmp_path / "bare"  # a run without its normalisation statistics
    bare.mkdir()
    for name in ("model.zip", "config.yaml"):
        (bare / name).write_bytes((Path(member) / name).read_bytes())
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("keep me\n")
    copy = tmp_path / "copy"  # a copied run folder: the same network under another name
    shutil.copytree(member, copy)
    (tmp_path / "junk.zip").write_text("not a model\n")
    cases = [([str(POLICY_DIR / "balance"), member, "--out", "e"], "trained with different residual"),
             ([member, str(ensemble_members(RESIDUAL)[1]), "--out", "full"], "already exists"),
             ([member, member, "--out", "e"], "are the same network"),
             ([member, str(copy), "--out", "e"], "are the same network"),
             ([str(tmp_path / "junk.zip"), member, "--out", "e"], "junk.zip: not a Stable-Baselines3 model"),
             ([member, "--out", "e"], "2 or more"),
             ([member, str(bare), "--out", "e"], "vecnormalize.pkl")]  # fmt: skip
    for args, message in cases:
        proc = sg_in(capfd, "ensemble", *args, cwd=tmp_path)
        lines = [line for line in proc.stderr.splitlines() if line.strip()]
        assert proc.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: "), proc.stderr[-2000:]
        assert message in lines[0], lines[0]
    assert not (tmp_path / "e").exists() and sorted(p.name for p in (tmp_path / "full").iterdir()) == ["keep.txt"]


def test_a_sampling_ensemble_averages_the_networks_samples() -> None:
    """``predict(deterministic=False)``: each network samples its own action and the ensemble sends their mean, so
    the samples stay within the bounds, vary from call to call, scatter less than one network's (independent
    noise, averaged over 6) and centre near the deterministic mean."""
    import torch

    torch.manual_seed(0)
    ensemble = load_policy(resolve_policy("shipped-residual")).learned
    obs = observations(1, 2)[0]
    one = np.stack([ensemble.members[0].predict(obs, deterministic=False)[0] for _ in range(400)])
    many = np.stack([ensemble.predict(obs, deterministic=False)[0] for _ in range(400)])
    low, high = ensemble.members[0].model.action_space.low, ensemble.members[0].model.action_space.high
    assert np.all(many >= low) and np.all(many <= high) and np.ptp(many, axis=0).min() > 0
    assert np.all(many.std(axis=0) < 0.7 * one.std(axis=0))
    np.testing.assert_allclose(many.mean(axis=0), ensemble.predict(obs)[0], atol=0.03)  # one network: 0.15 off


@pytest.mark.slow
def test_a_checkpoint_runs_with_its_own_statistics_and_ensembles(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """A checkpoint (``checkpoints/rl_model_<n>_steps.zip`` with ``rl_model_vecnormalize_<n>_steps.pkl`` beside it,
    as training writes them) evaluates as the same network in a run folder does, and ``ensemble`` takes
    checkpoints (a snapshot ensemble of one run). Without its statistics it is one ``error:`` line: the network
    would see raw observations. (The two checkpoints here are two members of the shipped residual ensemble: one
    recipe's networks, as a run's checkpoints are; two copies of one network would be refused.)"""
    member, earlier = ensemble_members(RESIDUAL)[:2]
    folder = tmp_path / "run" / "checkpoints"
    folder.mkdir(parents=True)
    (tmp_path / "run" / "config.yaml").write_text((member / "config.yaml").read_text())
    for steps, source in ((250_000, earlier), (300_000, member)):
        (folder / f"rl_model_{steps}_steps.zip").write_bytes((source / "model.zip").read_bytes())
        (folder / f"rl_model_vecnormalize_{steps}_steps.pkl").write_bytes((source / "vecnormalize.pkl").read_bytes())
    checkpoint = folder / "rl_model_300000_steps.zip"
    figures = {}
    for name, policy in (("run folder", str(member)), ("checkpoint", str(checkpoint))):
        proc = sg_in(capfd, "evaluate", "--policy", policy, "--episodes", "2", "--json", cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        figures[name] = json.loads(proc.stdout)
    for key in ("rms_error_mm", "final_error_mm", "settling_time_s", "settled_pulse_rate_us_per_s"):
        assert figures["checkpoint"][key] == pytest.approx(figures["run folder"][key], rel=1e-9)
    made = sg_in(capfd, "ensemble", str(folder / "rl_model_250000_steps.zip"), str(checkpoint), "--out", "snap",
                 cwd=tmp_path)  # fmt: skip
    assert made.returncode == 0, made.stderr[-2000:]
    assert all((m / "vecnormalize.pkl").is_file() for m in ensemble_members(tmp_path / "snap"))
    (folder / "rl_model_vecnormalize_300000_steps.pkl").unlink()
    lost = sg_in(capfd, "evaluate", "--policy", str(checkpoint), "--episodes", "1", cwd=tmp_path)
    errors = [ln for ln in lost.stderr.splitlines() if ln.startswith("error:")]
    assert lost.returncode == 1 and len(errors) == 1 and "statistics are not beside it" in errors[0]
    assert "Traceback" not in lost.stderr


@pytest.mark.slow
def test_train_checkpoints_make_a_snapshot_ensemble_of_one_run(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """``train --checkpoint-freq N`` saves a checkpoint with its statistics every N steps; ``ensemble`` averages
    checkpoints of that one run, and the result evaluates (the snapshot ensemble of the Control page)."""
    (tmp_path / "hp.yml").write_text("StewartBallBalance-v0:\n  n_envs: 1\n  n_timesteps: 64\n  normalize: true\n"
                                     "  policy: MlpPolicy\n  n_steps: 32\n  batch_size: 16\n  n_epochs: 1\n"
                                     "  policy_kwargs:\n    net_arch: [8]\n")  # fmt: skip
    run = sg_in(capfd, "train", "--hyperparams", "hp.yml", "--run-dir", "run", "--checkpoint-freq", "32", "--eval-freq",
                "32", "--eval-episodes", "1", "--no-progress", "--no-tensorboard", cwd=tmp_path)  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    folder = tmp_path / "run" / "checkpoints"
    for steps in (32, 64):
        assert (folder / f"rl_model_{steps}_steps.zip").is_file()
        assert (folder / f"rl_model_vecnormalize_{steps}_steps.pkl").is_file()
    made = sg_in(capfd, "ensemble", str(folder / "rl_model_32_steps.zip"), str(folder / "rl_model_64_steps.zip"), "--out",
              "snap", cwd=tmp_path)  # fmt: skip
    assert made.returncode == 0, made.stderr[-2000:]
    evaluated = sg_in(capfd, "evaluate", "--policy", "snap", "--episodes", "1", "--json", cwd=tmp_path)
    assert evaluated.returncode == 0, evaluated.stderr[-2000:]
    assert json.loads(evaluated.stdout)["episodes"] == 1
