"""Training smoke runs (each algorithm, a few hundred steps), evaluation, save/load round trips, the PID baseline."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from stewart_gym.cli import main
from stewart_gym.control import CascadedPID, PIDGains
from stewart_gym.errors import ConfigError
from stewart_gym.evaluation import evaluate, format_table
from stewart_gym.registry import load_policy
from stewart_gym.sb3_models import load_sb3
from stewart_gym.training import TrainConfig, load_hyperparams, train

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
    assert rows[0] == "timesteps,wall_s,mean_reward,success_rate" and len(rows) >= 3
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
    assert "(" + ", ".join(f"`{n}`" for n in names) + ")" in docs  # the list in the docs is the package's
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


def test_demo_compares_the_learned_policies_shipped_for_the_build_with_the_strongest_classical_ones() -> None:
    from stewart_gym.experiments import demo_policies

    env = "StewartBallBalance-v0"
    assert demo_policies(env, None) == ["shipped-residual", "shipped", "pid-kalman", "lqr"]
    assert demo_policies(env, "memememe-liverpool") == ["shipped", "pid-kalman", "lqr"]  # no residual shipped for it


def test_shipped_policy_files_are_small_and_complete() -> None:
    from stewart_gym.registry import POLICY_DIR

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


def test_shipping_a_policy_refuses_an_evaluation_file_without_json_before_touching_the_package(tmp_path: Path) -> None:
    """``train/tools/ship_policy.py --eval FILE`` reads the evaluation first: a file with no JSON object is one error line
    and nothing is written or removed under ``stewart_gym/policies``; an indented JSON object is read as it is."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
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

    root = Path(__file__).resolve().parents[1]
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


def test_results_page_re_evaluates_only_the_named_controllers(tmp_path: Path) -> None:
    """``train/tools/results.py --rows "LQR → PID"``: only that controller's rows are evaluated (balance, the three
    trajectories, latency and noise), every other row of results.json is kept, recipes included, and a
    re-evaluated row takes its old row's place; an unknown label, a --recipe run that does not exist, or no
    results.json to keep rows from, is refused with one error line and exit 2."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
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

    root, out = Path(__file__).resolve().parents[1], tmp_path / "h.json"
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


def experiment(name: str) -> list[str]:
    """The command that runs ``train/experiments/<name>.py`` as a user runs it, from the repository's root (``cwd``
    :data:`ROOT`): ``python -m train.experiments.<name>``."""
    import sys

    return [sys.executable, "-m", f"train.experiments.{name}"]


def run_experiment(name: str, args: list[str], out: Path) -> dict:
    """``python -m train.experiments.<name> ARGS --out OUT`` as a user runs it: exit 0, and the JSON line it wrote."""
    import subprocess

    proc = subprocess.run([*experiment(name), *args, "--out", str(out)], capture_output=True, text=True, timeout=600,
                          cwd=ROOT)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(out.read_text())


def test_memory_experiment_trains_and_evaluates_a_stacked_policy(tmp_path: Path) -> None:
    """``train/experiments/memory.py --stack 2`` for one PPO rollout: exits 0 and reports the Control page's
    metrics for the stacked policy (evaluated through the shared evaluation code); a bad size is refused."""
    import subprocess

    script = experiment("memory")
    result = run_experiment("memory", ["--stack", "2", "--steps", "256", "--episodes", "1"],
                            tmp_path / "m.json")  # fmt: skip
    assert result["stack"] == 2 and result["steps"] == 256 and 0.0 <= result["success_rate"] <= 1.0
    assert result["rms_error_mm"] > 0 and "settled_pulse_p2p_us" in result and "settling_time_s" in result
    bad = subprocess.run([*script, "--stack", "0"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert bad.returncode == 2 and "error:" in bad.stderr and "--stack" in bad.stderr


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


def test_builds_table_replaces_only_its_section(tmp_path: Path) -> None:
    """``train/tools/builds.py`` for one build and one controller, one episode: the table between the markers is
    replaced (a row per pair, every column filled) and the rest of the page is kept; with ``--dither-deg`` and
    ``--section`` a second table goes between its own markers; an unknown build, a dither of 20° and a page
    without markers are refused with one ``error:`` line before any evaluation."""
    import subprocess
    import sys

    root, page = Path(__file__).resolve().parents[1], tmp_path / "page.md"
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

    root = Path(__file__).resolve().parents[1]
    (tmp_path / "images").mkdir()

    def row(label: str, rms: list[float], final: list[float], settle: list[float]) -> dict:
        per = {"success": [True] * 4, "rms_mm": rms, "tail_steps": [250] * 4, "final_mm": final, "settling_s": settle}
        return {"table": "balance", "row": label, "policy": label, "estimator": None, "env": "StewartBallBalance-v0",
                "episodes": 4, "metrics": {"seed": 0, "success_rate": 1.0, "per_episode": per}}  # fmt: skip

    results = [row("LQR → PID", [1.0, 1.1, 0.9, 1.0], [0.5, 0.9, 0.4, 0.8], [0.6, 0.6, 0.7, 0.5]),
               row("PID + Kalman", [1.0, 1.0, 1.0, 1.0], [0.6, 0.6, 0.6, 0.6], [1.4, 1.5, 1.5, 1.4]),
               row("LQR", [2.0, 2.1, 1.9, 2.0], [1.0, 1.1, 0.9, 1.0], [0.6, 0.6, 0.7, 0.5])]  # fmt: skip
    del results[2]["metrics"]["per_episode"]  # an old results.json row: no paired comparison with it
    fewer = row("residual PPO", [0.9, 1.0, 1.1], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5])  # 3 seeds: not paired with 4
    fewer["metrics"]["per_episode"].update(success=[True] * 3, tail_steps=[250] * 3)
    results.append(fewer)
    (tmp_path / "results.json").write_text(json.dumps(results))
    proc = subprocess.run([sys.executable, str(root / "train" / "tools" / "results.py"), "--from-json", "--out",
                           str(tmp_path / "r.md")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    page = (tmp_path / "r.md").read_text()
    assert "paired: row minus row on the same 4 seeds" in page
    # the tables where train/tools/results_intro.md marks them: after the lead, before the controllers and the findings
    assert "<!-- tables -->" not in page
    assert page.index("## The tables") < page.index("paired: row minus row") < page.index("## The controllers") \
        < page.index("## Findings")
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

    root = Path(__file__).resolve().parents[1]
    (tmp_path / "images").mkdir()

    def track(label: str, rms: list[float]) -> dict:
        per = {"success": [True] * 4, "rms_mm": rms, "tail_steps": [250] * 4, "final_mm": rms}
        return {"table": "track circle", "row": label, "policy": label, "estimator": None,
                "env": "StewartBallTrack-v0", "episodes": 4, "env_kwargs": {"trajectory": "circle"},
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

    spec = importlib.util.spec_from_file_location("results_script", Path(__file__).resolve().parents[1] / "train"
                                                  / "tools" / "results.py")  # fmt: skip
    assert spec is not None and spec.loader is not None
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return script


def test_results_page_is_what_the_script_makes_of_results_json_and_the_intro() -> None:
    """docs/src/results.md is ``train/tools/results.py``'s page for ``docs/src/results.json`` and
    ``train/tools/results_intro.md`` as they are: an edit of the intro, or of the results, not regenerated
    (``--from-json``) fails here."""
    root = Path(__file__).resolve().parents[1]
    script = results_script()
    page = script.results_page(json.loads((root / "docs" / "src" / "results.json").read_text()))
    assert page == (root / "docs" / "src" / "results.md").read_text(), \
        "docs/src/results.md is stale: run .venv/bin/python train/tools/results.py --from-json"  # fmt: skip
    assert "| metric | shipped PPO | residual PPO | PID | PID + Kalman | LQR | LQR → PID |" in page


def test_readme_headline_is_the_results_json_table() -> None:
    """The README's headline table (between its markers) is what ``train/tools/results.py`` makes of
    ``docs/src/results.json``: no figure there goes stale when the results are regenerated; it names the
    shipped residual, the PID + Kalman and the LQR, and pairs the residual with both."""
    root = Path(__file__).resolve().parents[1]
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
    root = Path(__file__).resolve().parents[1]
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
