"""Training smoke runs (each algorithm, a few hundred steps), evaluation, save/load round trips, the PID baseline."""

from __future__ import annotations

import json
import re
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import cli

from stewart_gym.cli import main
from stewart_gym.control import CascadedPID, PIDGains
from stewart_gym.errors import ConfigError
from stewart_gym.evaluation import evaluate, format_table
from stewart_gym.registry import POLICY_DIR, load_policy
from stewart_gym.sb3_models import load_sb3
from stewart_gym.training import TrainConfig, load_hyperparams, rollout_note, train, whole_rollouts_note

SMOKE = {
    "ppo": {"n_steps": 128, "batch_size": 64, "n_epochs": 2},
    "sac": {"learning_starts": 100, "batch_size": 64, "buffer_size": 2000, "train_freq": 4, "gradient_steps": 1},
    "td3": {"learning_starts": 100, "batch_size": 64, "buffer_size": 2000, "train_freq": 4, "gradient_steps": 1,
            "noise_type": "normal", "noise_std": 0.1},
    "tqc": {"learning_starts": 100, "batch_size": 64, "buffer_size": 2000, "train_freq": 4, "gradient_steps": 1},
}

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("algo", sorted(SMOKE))
def test_train_save_load_evaluate_round_trip(algo: str, tmp_path: Path) -> None:
    hp = {"StewartBallBalance-v0": {"n_envs": 1, "n_timesteps": 300, "normalize": True, "policy": "MlpPolicy",
                                    "env_kwargs": {"randomize": True}, "policy_kwargs": {"net_arch": [16, 16]},
                                    **SMOKE[algo]}}  # fmt: skip
    hp_file = tmp_path / "hp.yml"
    hp_file.write_text(yaml.safe_dump(hp))
    run = tmp_path / "run"
    metrics = train(TrainConfig(algo=algo, hyperparams=str(hp_file), run_dir=str(run), eval_freq=150,
                                eval_episodes=1, checkpoint_freq=200, progress_bar=False, tensorboard=True))  # fmt: skip
    assert metrics["timesteps"] >= 300 and metrics["algo"] == algo
    for name in ("model.zip", "vecnormalize.pkl", "config.yaml", "git.txt", "metrics.json", "eval.csv"):
        assert (run / name).exists(), name
    assert (run / "best" / "best_model.zip").exists() and list((run / "checkpoints").glob("*.zip"))
    assert list((run / "tb").rglob("events.out.tfevents.*"))
    rows = (run / "eval.csv").read_text().splitlines()
    assert rows[0] == "timesteps,wall_s,mean_reward,success_rate,evaluated_s" and len(rows) >= 3
    taken = [float(r.split(",")[1]) for r in rows[1:]]
    evaluated = [float(r.split(",")[4]) for r in rows[1:]]
    assert taken == sorted(taken) and all(t <= e for t, e in zip(taken, evaluated))  # a snapshot, then its result
    # load: same actions as the trained model on the same normalised observations
    policy = load_sb3(run)
    obs = np.random.default_rng(0).normal(size=(5, 12)).astype(np.float32)
    expected = policy.model.predict(policy.normalize(obs), deterministic=True)[0]
    assert np.allclose(load_sb3(run / "model.zip").predict(obs)[0], expected)
    assert policy.obs_rms is not None and policy.obs_rms.mean.shape == (12,)
    m = evaluate("StewartBallBalance-v0", policy, episodes=1, seed=0, settling=False)
    assert 0.0 <= m["success_rate"] <= 1.0 and m["rms_error_mm"] >= 0
    # resume from the run folder continues counting timesteps
    more = train(TrainConfig(algo=algo, hyperparams=str(hp_file), run_dir=str(tmp_path / "run2"), resume=str(run),
                             n_timesteps=200, eval_freq=1000, eval_episodes=1, progress_bar=False,
                             tensorboard=False))  # fmt: skip
    assert more["timesteps"] >= metrics["timesteps"] + 200
    # ... with the observations scaled as the resumed policy was trained (the rewards' scale keeps learning), in
    # statistics saved as SB3's own, which load without this package's training module
    import pickle

    from stable_baselines3.common.running_mean_std import RunningMeanStd

    before, after = (pickle.loads((r / "vecnormalize.pkl").read_bytes()) for r in (run, tmp_path / "run2"))
    assert type(after.obs_rms) is RunningMeanStd
    assert np.array_equal(after.obs_rms.mean, before.obs_rms.mean) and after.obs_rms.count == before.obs_rms.count
    assert after.ret_rms.count > before.ret_rms.count
    # ... and with its own seed, not the resumed model's
    other = train(TrainConfig(algo=algo, hyperparams=str(hp_file), run_dir=str(tmp_path / "run2s1"), resume=str(run),
                              n_timesteps=200, eval_freq=1000, eval_episodes=1, progress_bar=False, tensorboard=False,
                              seed=1))  # fmt: skip
    assert other["seed"] == 1
    with zipfile.ZipFile(tmp_path / "run2" / "model.zip") as a, zipfile.ZipFile(tmp_path / "run2s1" / "model.zip") as b:
        assert a.read("policy.pth") != b.read("policy.pth")
    # resume from the best model takes the statistics saved beside it (once, it silently started fresh ones)
    from stewart_gym.training import check_run_dir, resume_statistics

    assert resume_statistics(run / "best" / "best_model.zip") == run / "best" / "vecnormalize.pkl"
    checkpoint = sorted((run / "checkpoints").glob("rl_model_*_steps.zip"))[0]
    assert resume_statistics(checkpoint).name.startswith("rl_model_vecnormalize_")
    lone = tmp_path / "lone"
    lone.mkdir()
    (lone / "model.zip").write_bytes((run / "model.zip").read_bytes())
    with pytest.raises(ConfigError, match="normalisation statistics"):
        check_run_dir(TrainConfig(algo=algo, hyperparams=str(hp_file), run_dir=str(tmp_path / "run3"),
                                  resume=str(lone / "model.zip")))  # fmt: skip


def test_a_resumed_run_goes_on_with_its_own_recipe_and_in_place_with_its_learning_curve(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``--resume RUN`` without ``--hyperparams`` trains with the run's own recipe (here ppo_batched's copies on
    the batched backend, not ppo.yml's two PyBullet envs) and says so; resumed in place, the learning curve, its
    ``evaluations.npz`` and the best model go on instead of starting again."""
    import csv

    run = tmp_path / "run"
    common = ["--eval-freq", "4096", "--eval-episodes", "2", "--no-progress", "--no-tensorboard"]
    code, _, err = cli(capfd, "train", "--hyperparams", "ppo_batched", "--run-dir", str(run), "--timesteps", "8192",
                       *common)  # fmt: skip
    assert code == 0, err
    before = list(csv.DictReader((run / "eval.csv").open()))
    best = (run / "best" / "best_model.zip").read_bytes()
    assert [int(r["timesteps"]) for r in before] == [4096, 8192]
    code, _, err = cli(capfd, "train", "--resume", str(run), "--run-dir", str(run), "--timesteps", "4096", *common)
    assert code == 0, err
    assert f"note: --resume {run}: its own recipe goes on ({run / 'config.yaml'})" in err
    recorded = yaml.safe_load((run / "config.yaml").read_text())["hyperparams"]
    assert recorded["env_kwargs"]["backend"] == "batched" and recorded["n_envs"] == load_hyperparams(
        "ppo", "StewartBallBalance-v0", "ppo_batched")["n_envs"]  # fmt: skip
    after = list(csv.DictReader((run / "eval.csv").open()))
    assert after[:2] == before and [int(r["timesteps"]) for r in after] == [4096, 8192, 12288]
    assert np.load(run / "eval" / "evaluations.npz")["timesteps"].tolist() == [4096, 8192, 12288]
    rewards = [float(r["mean_reward"]) for r in after]
    assert ((run / "best" / "best_model.zip").read_bytes() == best) == (rewards[2] <= max(rewards[:2]))
    # the best model resumed in place: the curve goes on from its steps (the later evaluations are dropped), and a
    # curve in an older layout (no evaluated_s) goes on in this one
    best_steps = int(after[int(np.argmax(rewards))]["timesteps"])
    lines = (run / "eval.csv").read_text().splitlines()
    (run / "eval.csv").write_text("\n".join(",".join(line.split(",")[:4]) for line in lines) + "\n")
    code, _, err = cli(capfd, "train", "--resume", str(run / "best" / "best_model.zip"), "--run-dir", str(run),
                       "--timesteps", "4096", *common)  # fmt: skip
    assert code == 0, err
    again = list(csv.DictReader((run / "eval.csv").open()))
    steps = [int(r["timesteps"]) for r in again]
    assert steps == sorted(set(steps)) and steps[-1] == best_steps + 4096
    assert list(again[0]) == ["timesteps", "wall_s", "mean_reward", "success_rate", "evaluated_s"]
    assert np.load(run / "eval" / "evaluations.npz")["timesteps"].tolist() == steps
    assert json.loads((run / "metrics.json").read_text())["timesteps"] == best_steps + 4096


def test_a_resumed_runs_recipe_is_named_in_its_errors_and_a_run_of_another_env_says_which_recipe_trains(
        tmp_path: Path) -> None:  # fmt: skip
    """A mistake in the resumed run's own recipe names its config.yaml (not ppo.yml, which it does not use); a run
    trained on another env, resumed for this one, says that the algorithm's file trains it."""
    from stewart_gym.training import check_run_dir, resume_note

    shipped = yaml.safe_load((Path(__file__).resolve().parents[1] / "stewart_gym/policies/balance/config.yaml").read_text())
    run = tmp_path / "run"
    run.mkdir()
    bad = {**shipped, "hyperparams": {**shipped["hyperparams"], "learning_rate": 2.0}}
    (run / "config.yaml").write_text(yaml.safe_dump(bad))
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(run / 'config.yaml'))}: learning_rate must be"):
        check_run_dir(TrainConfig(run_dir=str(tmp_path / "new"), resume=str(run)))
    (run / "config.yaml").write_text(yaml.safe_dump(shipped))
    assert resume_note(TrainConfig(resume=str(run))) == (f"--resume {run}: its own recipe goes on "
                                                         f"({run / 'config.yaml'}); --hyperparams gives another")
    note = resume_note(TrainConfig(env_id="StewartBallTrack-v0", resume=str(run)))
    assert "no recipe of its own for StewartBallTrack-v0 with PPO" in note and "ppo.yml's" in note
    assert resume_note(TrainConfig(resume=str(run), hyperparams="ppo_finetune")) is None


def test_a_resumed_policy_keeps_its_observer(tmp_path: Path) -> None:
    """Resuming the shipped balance PPO (trained behind the Kalman observer) with hyperparameters that put it
    behind the low-pass one is one error line from the command line, before any run folder; --estimator keeps
    the observer (or changes it on purpose), and hyperparameters with the same observer pass."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    shipped = root / "stewart_gym/policies/balance"
    proc = subprocess.run([sys.executable, "-m", "stewart_gym", "train", "--resume", str(shipped), "--hyperparams",
                           str(root / "stewart_gym/hyperparams/ppo_finetune.yml"), "--run-dir", str(tmp_path / "r")],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith("error: --resume") and "kalman observer" in proc.stderr
    assert "--estimator kalman" in proc.stderr and not (tmp_path / "r").exists()
    from stewart_gym.training import check_run_dir

    for estimator in ("kalman", "lowpass"):  # an explicit choice is the user's
        check_run_dir(TrainConfig(hyperparams=str(root / "stewart_gym/hyperparams/ppo_finetune.yml"),
                                  run_dir=str(tmp_path / estimator), resume=str(shipped), estimator=estimator))
    check_run_dir(TrainConfig(hyperparams="ppo_camera", run_dir=str(tmp_path / "c"),
                              resume=str(shipped / "model.zip")))  # the camera recipe keeps the Kalman observer
    with pytest.raises(ConfigError, match="lowpass observer"):  # and the other way round (desk-rect's: low-pass)
        check_run_dir(TrainConfig(hyperparams="ppo_camera",
                                  run_dir=str(tmp_path / "d"), resume=str(root / "stewart_gym/policies/balance_desk_rect")))


def test_hyperparameter_files_have_every_env() -> None:
    """Every algorithm the command line offers (the same as training's) has a file with every env; the command
    line's --vec-env names are training's too."""
    import stewart_gym
    from stewart_gym.cli.learning import ALGO_CHOICES, VEC_ENV_CHOICES
    from stewart_gym.training import ALGOS, VEC_ENVS

    assert sorted(ALGO_CHOICES) == sorted(ALGOS) and sorted(VEC_ENV_CHOICES) == sorted(VEC_ENVS)
    for algo in ALGO_CHOICES:
        for env_id in stewart_gym.ENV_IDS:
            hp = load_hyperparams(algo, env_id)
            assert hp["n_timesteps"] > 0 and hp["n_envs"] >= 1
    with pytest.raises(ConfigError, match="no section"):
        load_hyperparams("ppo", "CartPole-v1")


def test_shipped_recipes_load_by_name_and_the_docs_list_them() -> None:
    from stewart_gym.training import hyperparams_path, shipped_recipes

    names = shipped_recipes()
    assert {"ppo", "ppo_residual"} <= set(names)
    for name in names:
        assert hyperparams_path(name).is_file() and load_hyperparams("ppo", "StewartBallBalance-v0", name)
    docs = (Path(__file__).resolve().parents[1] / "docs/src/training.md").read_text()
    table = docs.split("| recipe | what it trains |\n", 1)[1].split("\n\n", 1)[0]
    listed = {name for row in table.splitlines()[1:] for name in re.findall(r"`(\w+)`", row.split("|")[1])}
    assert listed == set(names), listed ^ set(names)  # the recipes table is the package's
    with pytest.raises(ConfigError, match="neither a file nor a shipped recipe"):
        hyperparams_path("ppo_residul")


@pytest.mark.parametrize("field,value", [("n_timesteps", 0), ("n_envs", 0), ("eval_freq", -5), ("eval_episodes", 0),
                                         ("algo", "a2c"), ("vec_env", "threads")])  # fmt: skip
def test_train_refuses_bad_options_before_starting(field: str, value: object, tmp_path: Path) -> None:
    """A zero is an error, not "use the YAML's value"; nothing is written."""
    from stewart_gym.training import TrainConfig, train

    with pytest.raises(ConfigError, match=field.split("_")[0]):
        train(TrainConfig(run_dir=str(tmp_path / "run"), **{field: value}))
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("algo,noise,match", [
    ("ppo", {"noise_type": "normal", "noise_std": 0.1}, "for sac, td3, tqc; PPO explores"),
    ("td3", {"noise_type": "pink", "noise_std": 0.1}, "noise_type"),
    ("td3", {"noise_std": 0.1}, "noise_type"),
    ("sac", {"noise_type": "normal"}, "noise_std"),
    ("tqc", {"noise_type": "normal", "noise_std": 0.0}, "noise_std"),
    ("td3", {"noise_type": "normal", "noise_std": float("nan")}, "noise_std"),
    ("td3", {"noise_type": "normal", "noise_std": True}, "noise_std"),
    ("td3", {"noise_type": "normal", "noise_std": 1.5}, "noise_std"),
])  # fmt: skip
def test_bad_action_noise_is_refused_before_starting(algo: str, noise: dict, match: str, tmp_path: Path) -> None:
    hp_file = tmp_path / "hp.yml"
    hp_file.write_text(yaml.safe_dump({"StewartBallBalance-v0": {"n_envs": 1, **noise}}))
    with pytest.raises(ConfigError, match=match):
        train(TrainConfig(algo=algo, hyperparams=str(hp_file), run_dir=str(tmp_path / "run")))
    assert not (tmp_path / "run").exists()


def test_action_noise_is_the_one_the_yaml_names() -> None:
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    from stewart_gym.training import action_noise

    assert action_noise({"n_envs": 2}, 2) is None
    normal = action_noise({"noise_type": "normal", "noise_std": 0.2}, 3)
    assert isinstance(normal, NormalActionNoise)
    draws = np.array([normal() for _ in range(4000)])
    assert draws.shape == (4000, 3) and np.allclose(draws.std(axis=0), 0.2, rtol=0.1)
    assert isinstance(action_noise({"noise_type": "ornstein-uhlenbeck", "noise_std": 0.2}, 2),
                      OrnsteinUhlenbeckActionNoise)


def test_pid_balances_the_ball() -> None:
    m = evaluate("StewartBallBalance-v0", CascadedPID(PIDGains(kp_pos=1.5, kp_vel=4.0, ki_vel=2.0)), episodes=4,
                 seed=0, randomize=False)  # fmt: skip
    assert m["success_rate"] == 1.0 and m["rms_error_mm"] < 5.0
    assert m["settled_fraction"] == 1.0 and 0.5 < m["settling_time_s"] < 10.0
    assert "success rate" in format_table({"pid": m})


def test_pid_gains_round_trip(tmp_path: Path) -> None:
    pid = CascadedPID(PIDGains(kp_pos=2.5, kp_vel=6.0, ki_vel=1.5))
    pid.save(tmp_path / "g.json")
    again = load_policy(str(tmp_path / "g.json"))
    obs = np.random.default_rng(1).normal(size=(3, 12))
    assert np.array_equal(again.predict(obs)[0], CascadedPID(pid.gains).predict(obs)[0])


def test_evaluate_cli_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--env", "StewartBallBalance-v0", "--policy", "pid", "--episodes", "2", "--seed", "3",
                 "--json"]) == 0  # fmt: skip
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in ("success_rate", "rms_error_mm", "settling_time_s", "final_error_mm", "max_tilt_deg",
                "pulse_rate_us_per_s"):  # fmt: skip
        assert key in out
    assert out["episodes"] == 2 and out["seed"] == 3


def test_per_episode_values_give_back_every_pooled_metric(capsys: pytest.CaptureFixture[str]) -> None:
    """``evaluate --json`` keeps each seed's values; recomputed from them (as the paired comparison does), every
    pooled metric is the one it reports; a result compared with itself differs by exactly 0."""
    from stewart_gym.evaluation import PAIRED_METRICS, paired_difference, pooled_rms

    assert main(["evaluate", "--policy", "pid", "--episodes", "3", "--seed", "5", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    per = out["per_episode"]
    assert all(len(per[k]) == 3 for k in ("success", "rms_mm", "tail_steps", "final_mm", "settling_s"))
    assert per["tail_steps"] == [250, 250, 250]
    pooled = np.sqrt(np.average(np.square(per["rms_mm"]), weights=per["tail_steps"]))
    assert pooled == pytest.approx(out["rms_error_mm"], rel=1e-9)
    assert float(pooled_rms(per["rms_mm"], per["tail_steps"])) == pytest.approx(out["rms_error_mm"], rel=1e-9)
    assert np.mean(per["final_mm"]) == pytest.approx(out["final_error_mm"], rel=1e-9)
    assert np.mean(per["success"]) == out["success_rate"]
    assert np.mean([t for t in per["settling_s"] if t is not None]) == pytest.approx(out["settling_time_s"], rel=1e-9)
    for metric in PAIRED_METRICS:
        assert paired_difference(out, out, metric) == (0.0, 0.0, 0.0)


def test_paired_difference_pairs_seeds_and_weighs_tails() -> None:
    """Hand-made evaluations: a constant shift on every seed is the difference with a zero-width interval;
    the pooled RMS weighs each episode's tail length; settling compares only seeds where both settled; a
    comparison on other seeds is refused."""
    from stewart_gym.evaluation import paired_difference

    def result(rms: list[float], tails: list[int], final: list[float], settle: list[float | None]) -> dict:
        return {"seed": 0, "per_episode": {"success": [True] * len(rms), "rms_mm": rms, "tail_steps": tails,
                                           "final_mm": final, "settling_s": settle}}  # fmt: skip

    a = result([1.0, 3.0], [250, 50], [1.0, 2.0], [0.5, None])
    b = result([1.0, 1.0], [250, 250], [0.5, 1.5], [1.0, 2.0])
    diff, low, high = paired_difference(a, b, "final_error_mm")
    assert (diff, low, high) == pytest.approx((0.5, 0.5, 0.5))
    rms_a = np.sqrt((250 * 1.0 + 50 * 9.0) / 300)  # 1.53 mm, not the unweighted 2.24
    assert paired_difference(a, b, "rms_error_mm")[0] == pytest.approx(rms_a - 1.0)
    assert paired_difference(a, b, "settling_time_s") == pytest.approx((-0.5, -0.5, -0.5))  # seed 0 only
    with pytest.raises(ValueError, match="same seeds"):
        paired_difference(a, {**b, "seed": 100}, "final_error_mm")
    with pytest.raises(ValueError, match="metric must be"):
        paired_difference(a, b, "tilt")


@pytest.mark.slow
def test_demo_writes_table_gif_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--episodes", "2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "success rate" in out and "(policy shipped-residual)" in out
    metrics = json.loads((tmp_path / "demo_metrics.json").read_text())
    names = ["shipped-residual", "shipped", "pid-kalman", "lqr"]
    assert list(metrics) == names and all(metrics[n]["episodes"] == 2 for n in names)
    assert any(all(n in line for n in names) for line in out.splitlines())  # the table's header
    for other in names[1:]:  # the residual paired with each of the others on the same seeds
        assert f"shipped-residual − {other}, seed by seed" in out
    # each ran as itself: the end-to-end PPO, which sees no error integral, holds the ball looser than the residual,
    # whose PID holds it (seeds 0 and 1: about 2.0 against 0.6-0.7 mm RMS)
    assert metrics["shipped"]["rms_error_mm"] > 1.5 * metrics["shipped-residual"]["rms_error_mm"]
    assert (tmp_path / "demo.gif").stat().st_size > 50_000 and (tmp_path / "demo_pulses.png").stat().st_size > 20_000


def test_demo_on_the_batched_backend_writes_all_but_the_gif_and_says_why(tmp_path: Path,
                                                                        capfd: pytest.CaptureFixture[str]) -> None:
    """The batched backend draws nothing: the demo says so at its start and writes the table and the plot."""
    code, out, err = cli(capfd, "demo", "--backend", "batched", "--episodes", "1", "--workers", "1", "--out",
                         str(tmp_path))  # fmt: skip
    assert code == 0, err
    assert "note: no GIF: the batched backend does not render" in err and "Traceback" not in err
    assert "(batched)" in out and (tmp_path / "demo_metrics.json").is_file() and (tmp_path / "demo_pulses.png").is_file()
    assert not (tmp_path / "demo.gif").exists()


@pytest.mark.slow
def test_a_demo_stopped_while_it_draws_leaves_its_folder_as_it_was(tmp_path: Path) -> None:
    """Ctrl-C after the tables, while the demo runs the episode it draws: one line, exit 130, and the folder holds
    the last run's three files unchanged (not a new table beside an old GIF)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "demo"
    out.mkdir()
    for name in ("demo_metrics.json", "demo.gif", "demo_pulses.png"):
        (out / name).write_text("the last run's\n")
    proc = subprocess.Popen([sys.executable, "-m", "stewart_gym", "demo", "--episodes", "2", "--workers", "1", "--out",
                             str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,  # no progress line: a slow machine's would come first
                            env={**os.environ, "PYTHONUNBUFFERED": "1", "STEWART_GYM_PROGRESS_S": "86400"})  # fmt: skip
    try:
        for line in proc.stdout:  # the last paired table's heading: the figures' episode (seconds) comes next
            if line.startswith("shipped-residual − lqr, seed by seed"):
                break
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130 and err.strip().splitlines() == [
        "error: stopped by Ctrl-C (SIGINT) before the command finished"], err
    assert sorted(p.name for p in out.iterdir()) == ["demo.gif", "demo_metrics.json", "demo_pulses.png"]
    assert all((out / name).read_text() == "the last run's\n" for name in ("demo_metrics.json", "demo.gif"))


def test_demo_compares_the_learned_policies_shipped_for_the_build_with_the_strongest_classical_ones() -> None:
    from stewart_gym.experiments import demo_policies

    env = "StewartBallBalance-v0"
    assert demo_policies(env, None) == ["shipped-residual", "shipped", "pid-kalman", "lqr"]
    assert demo_policies(env, "memememe-liverpool") == ["shipped", "pid-kalman", "lqr"]  # no residual shipped for it


def test_shipped_policy_files_are_small_and_complete() -> None:
    folder = POLICY_DIR / "balance"
    for name in ("model.zip", "vecnormalize.pkl", "config.yaml", "metrics.json", "eval.csv", "bundle/policy.onnx",
                 "bundle/bundle.json"):  # fmt: skip
        assert (folder / name).exists(), name
    assert sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) < 2_000_000
    policy = load_policy("shipped")
    obs = np.zeros((1, 12), dtype=np.float32)
    assert policy.predict(obs)[0].shape == (1, 2)


def test_settled_servo_activity_is_reported() -> None:
    """``evaluate`` reports the last 5 s of servo motion: mean |ΔW| per servo per second and the largest channel's
    peak-to-peak, as recomputed here from the episode's own pulse log."""
    import gymnasium as gym

    from stewart_gym.evaluation import run_episode
    from stewart_gym.registry import load_for_evaluation

    _, pid, kwargs = load_for_evaluation("pid", "StewartBallBalance-v0", None)
    m = evaluate("StewartBallBalance-v0", pid, episodes=1, seed=7, settling=False, env_kwargs=kwargs)
    env = gym.make("StewartBallBalance-v0", randomize=True, **kwargs)
    pid.reset()
    log = run_episode(env, pid, 7)
    env.close()
    tail = np.asarray(log.pulses[-250:])
    assert not log.fell
    assert m["settled_pulse_p2p_us"] == pytest.approx(np.ptp(tail, axis=0).max())
    assert m["settled_pulse_rate_us_per_s"] == pytest.approx(np.abs(np.diff(tail, axis=0)).mean() / 0.02)
    assert 0 < m["settled_pulse_rate_us_per_s"] < 5000 and 0 < m["settled_pulse_p2p_us"] < 400


def test_an_episode_renders_only_the_frames_asked_for() -> None:
    """``run_episode(frame_every=k)``: a frame after every k-th step, each one rendered then (the plate moves
    between them); none without; a bad k is refused before the episode."""
    import gymnasium as gym

    from stewart_gym.evaluation import run_episode
    from stewart_gym.registry import load_for_evaluation

    _, pid, kwargs = load_for_evaluation("pid", "StewartBallBalance-v0", None)
    env = gym.make("StewartBallBalance-v0", render_mode="rgb_array", episode_s=0.5, **kwargs)
    rendered = []
    render = env.render

    def counted():
        rendered.append(len(rendered))
        return render()

    env.render = counted
    try:
        start = {"ball_position": (0.08, 0.0), "ball_velocity": (0.0, 0.0)}
        log = run_episode(env, pid, 3, start, frame_every=5)
        assert len(log.distance_mm) == 25 and log.frame_every == 5
        assert len(log.frames) == len(rendered) == 5 and log.frames[0].ndim == 3
        assert not np.array_equal(log.frames[0], log.frames[-1])
        assert run_episode(env, pid, 3, start).frames == [] and len(rendered) == 5
        for bad in (-1, 1.5, True):
            with pytest.raises(ValueError, match="frame_every"):
                run_episode(env, pid, 3, start, frame_every=bad)
    finally:
        env.close()


def test_make_results_reproduces_every_recipe_column_of_the_page() -> None:
    """Every recipe column of the committed results.json is one that `make results` evaluates, with the same
    runs: regenerating the page from scratch keeps its columns."""
    import re

    root = Path(__file__).resolve().parents[1]
    makefile = (root / "Makefile").read_text()
    variables = dict(re.findall(r"^(\w+) :?= (.*)$", makefile, flags=re.M))
    target = makefile.split("\nresults:", 1)[1].split("\n\n", 1)[0]
    made = {}
    for label, runs in re.findall(r'--recipe "([^"=]+)=([^"]+)"', target):
        made[label] = [re.sub(r"\$\((\w+)\)", lambda m: variables[m.group(1)], run) for run in runs.split(",")]
    rows = json.loads((root / "docs/src/results.json").read_text())
    on_page: dict[str, list[str]] = {}
    for r in rows:
        if r["row"].startswith("seed:") and r["row"][5:] not in on_page.setdefault(r["recipe"], []):
            on_page[r["recipe"]].append(r["row"][5:])
    assert on_page and on_page == made


def test_env_copies_step_alike_in_this_process_and_in_worker_processes() -> None:
    """``--vec-env dummy`` and ``subproc`` see the same transitions to the last bit, episode ends included, and
    both give float64 rewards (SB3's DummyVecEnv would round them to float32, and so train another network)."""
    from stewart_gym.training import VEC_ENVS, make_env

    seen = {}
    for name in VEC_ENVS:
        venv = make_env("StewartBallBalance-v0", 2, 3, {"randomize": True, "estimator": "kalman"}, vec_env=name)
        rng = np.random.default_rng(0)
        obs, rewards, dones = [venv.reset()], [], []
        for _ in range(400):  # random tilts drop the ball: episodes end and reset on their own
            o, r, d, _ = venv.step(rng.uniform(-1, 1, (2, *venv.action_space.shape)).astype(np.float32))
            obs.append(o)
            rewards.append(r)
            dones.append(d)
        venv.close()
        seen[name] = np.array(obs), np.array(rewards), np.array(dones)
    (obs_a, rew_a, done_a), (obs_b, rew_b, done_b) = seen["dummy"], seen["subproc"]
    assert done_a.any() and rew_a.dtype == rew_b.dtype == np.float64
    assert np.array_equal(obs_a, obs_b) and np.array_equal(rew_a, rew_b) and np.array_equal(done_a, done_b)
    assert not np.array_equal(rew_a, rew_a.astype(np.float32))  # float32 would have rounded these rewards


def test_the_batched_backend_trains_behind_cameras(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``train --hyperparams ppo_batched --sensor camera`` trains on the batched backend behind a camera preset
    drawn per episode, and the run evaluates behind a camera by default."""
    run = tmp_path / "run"
    assert main(["train", "--hyperparams", "ppo_batched", "--sensor", "camera", "--run-dir", str(run),
                 "--n-envs", "32", "--timesteps", "1024", "--eval-freq", "100000", "--no-progress"]) == 0  # fmt: skip
    recorded = yaml.safe_load((run / "config.yaml").read_text())["hyperparams"]
    assert recorded["env_kwargs"]["backend"] == "batched" and recorded["env_kwargs"]["sensor"] == "camera"
    capsys.readouterr()
    assert main(["evaluate", "--policy", str(run), "--episodes", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["sensor"] == "camera" and result["backend"] == "pybullet"


def test_the_rollout_note_counts_the_minibatches(tmp_path: Path) -> None:
    """A rollout that batch_size does not divide is a note that counts the whole minibatches and the rest; one
    that it divides, a resumed run and an off-policy algorithm none."""
    def note(**kw: object) -> str | None:
        return rollout_note(TrainConfig(**{"hyperparams": "ppo_batched", "run_dir": "unused", **kw}))

    assert note(n_envs=100) == ("n_steps 32 × n_envs 100 = a rollout of 3,200 samples, which batch_size 1,024 does not "
                                "divide: each epoch trains on 3 minibatches of 1,024 and one of 128 (for whole "
                                "minibatches, make n_steps × n_envs a multiple of batch_size; the recipe has n_envs "
                                "128)")  # fmt: skip
    assert "1 minibatch of 1,024 and one of 32 (" in note(n_envs=33)
    assert note() is None and note(n_envs=96) is None  # 4,096 and 3,072 samples: 4 and 3 minibatches
    assert note(n_envs=100, resume=str(POLICY_DIR / "balance")) is None
    assert rollout_note(TrainConfig(algo="sac", run_dir="unused", n_envs=3)) is None
    recipe = tmp_path / "no_n_envs.yml"  # n_envs left to the default (1)
    recipe.write_text("StewartBallBalance-v0:\n  n_steps: 48\n  batch_size: 64\n")
    assert note(hyperparams=str(recipe), n_envs=3).endswith("and one of 16 (for whole minibatches, make n_steps × "
                                                            "n_envs a multiple of batch_size; the recipe has n_envs 1)")


def test_timesteps_that_are_not_whole_rollouts_are_a_note_saying_what_trains(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """PPO collects whole rollouts: ``--timesteps`` short of one (or between two) says how many steps it trains, and
    the run does train that many; whole rollouts, a resumed run and off-policy algorithms give no note."""
    def note(**kw: object) -> str | None:
        return whole_rollouts_note(TrainConfig(**{"hyperparams": "ppo_batched", "run_dir": "unused", **kw}))

    assert note(n_timesteps=128) == ("PPO collects whole rollouts of n_steps × n_envs = 4,096 steps: 128 timesteps "
                                     "train 4,096")  # fmt: skip
    assert note(n_timesteps=5000).endswith("5,000 timesteps train 8,192")
    assert note(n_timesteps=8192) is None and note(n_timesteps=128, resume=str(POLICY_DIR / "balance")) is None
    assert note() is None  # the recipe's own 300,000 trains 303,104 too, without a word: the recipe's choice
    assert whole_rollouts_note(TrainConfig(algo="sac", run_dir="unused", n_timesteps=7)) is None
    code, out, err = cli(capfd, "train", "--hyperparams", "ppo_batched", "--run-dir", str(tmp_path / "run"),
                         "--timesteps", "128", "--eval-freq", "100000", "--eval-episodes", "1", "--no-progress",
                         "--no-tensorboard")  # fmt: skip
    assert code == 0, err
    assert "note: PPO collects whole rollouts of n_steps × n_envs = 4,096 steps: 128 timesteps train 4,096" in err
    assert json.loads(out)["timesteps"] == 4096


@pytest.mark.slow
def test_a_policy_trained_on_the_batched_backend_runs_in_every_engine(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``train --hyperparams ppo_batched`` trains on the batched backend (its copies on one batched simulator);
    the run then evaluates without complaint in PyBullet (the default for it), MuJoCo and the batched backend, and
    ``compare`` runs it, beside a classical controller or a PyBullet-trained policy, in PyBullet too unless told
    otherwise."""
    run = tmp_path / "run"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["train", "--hyperparams", "ppo_batched", "--run-dir", str(run), "--n-envs", "16",
                     "--timesteps", "2048", "--eval-freq", "1024", "--eval-episodes", "2"]) == 0  # fmt: skip
    # 16 copies × 32 steps fill half of one of the recipe's minibatches: a note line says so, SB3's warning not
    notes = [line for line in capsys.readouterr().err.splitlines() if line.startswith("note: ")]
    assert notes == ["note: n_steps 32 × n_envs 16 = a rollout of 512 samples, which batch_size 1,024 does not "
                     "divide: each epoch trains on one minibatch of 512 (for whole minibatches, make n_steps × n_envs "
                     "a multiple of batch_size; the recipe has n_envs 128)"], notes  # fmt: skip
    assert not [w for w in caught if "mini-batch size" in str(w.message)]
    recorded = yaml.safe_load((run / "config.yaml").read_text())["hyperparams"]
    assert recorded["env_kwargs"]["backend"] == "batched"
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["n_envs"] == 16 and metrics["timesteps"] >= 2048 and metrics["last_eval"]["timesteps"] >= 1024
    capsys.readouterr()
    for backend, engine in ((None, "pybullet"), ("mujoco", "mujoco"), ("batched", "batched")):
        extra = ["--backend", backend] if backend else []
        assert main(["evaluate", "--policy", str(run), "--episodes", "1", "--json", *extra]) == 0
        result = json.loads(capsys.readouterr().out)
        assert result["backend"] == engine and result["episodes"] == 1
    for other in ("lqr", "shipped"):  # a classical controller; the shipped policy, trained in PyBullet
        for pair in ([str(run), other], [other, str(run)]):
            assert main(["compare", *pair, "--episodes", "2", "--json"]) == 0
            assert json.loads(capsys.readouterr().out)["backend"] == "pybullet", pair


@pytest.mark.parametrize("checks", [True, False], ids=["torch-checks-on", "torch-checks-off"])
def test_a_network_that_turns_to_nan_ends_in_one_line_whatever_torch_checks(
        checks: bool, tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """Whether torch's distributions check their arguments or not (TorchRL, once imported, turns the checks off for
    the whole process), a run whose network turns to NaN ends with the same ``error: training diverged`` line."""
    import torch

    (tmp_path / "diverges.yml").write_text("StewartBallBalance-v0:\n  n_envs: 2\n  n_steps: 16\n  batch_size: 32\n"
                                           "  vf_coef: 1.0e+300\n  n_timesteps: 256\n  env_kwargs: {backend: batched}\n")
    before = torch.distributions.Distribution._validate_args
    torch.distributions.Distribution.set_default_validate_args(checks)
    try:
        code, _, err = cli(capfd, "train", "--hyperparams", str(tmp_path / "diverges.yml"), "--run-dir",
                           str(tmp_path / "r"), "--no-progress", "--no-tensorboard", cwd=tmp_path)  # fmt: skip
    finally:
        torch.distributions.Distribution.set_default_validate_args(before)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 1 and len(lines) == 1, err
    assert lines[0].startswith("error: training diverged after 32 steps: the network gave NaN"), err
