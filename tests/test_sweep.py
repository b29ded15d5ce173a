"""``stewart-gym sweep``: the sweep file's checks, and real sweeps on Ray run as a user runs them (subprocesses):
on a local Ray, on a two-node cluster on this machine, with a failing trial, and interrupted then resumed."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

ray = pytest.importorskip("ray", reason="the [cluster] extra (make test installs it)")

#: `make test` runs the suite on several workers; every Ray cluster of this file starts on the same one.
pytestmark = pytest.mark.xdist_group("ray")

from conftest import sg  # noqa: E402

from stewart_gym.errors import ConfigError  # noqa: E402
from stewart_gym.sweep import SweepSpec, load_sweep, rank_trials, summarise_configs, trial_overrides  # noqa: E402

#: A tiny PPO run: the sweeps here check the machinery, not what the agent learns.
TINY = {"env": "StewartBallBalance-v0", "algo": "ppo", "n_timesteps": 1024, "n_envs": 1, "n_steps": 256,
        "batch_size": 64, "n_epochs": 2, "eval_freq": 512, "eval_episodes": 1}  # fmt: skip


def write(folder: Path, name: str = "sweep.yaml", **entries: object) -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump({**TINY, **entries}, sort_keys=False))
    return path


def rows(out: Path) -> list[dict[str, str]]:
    with (out / "results.csv").open() as fh:
        return list(csv.DictReader(fh))


def check_bundle_deploys(bundle: Path) -> None:
    """The bundle loads in deploy's policy loader (numpy + onnxruntime) and gives a finite action in [-1, 1]."""
    from stewart_gym.registry import deployable_policy, resolve_policy

    policy = deployable_policy(resolve_policy(str(bundle)))
    action = np.asarray(policy(np.zeros(12, dtype=np.float32)))
    assert action.shape == (2,) and np.all(np.isfinite(action)) and np.all(np.abs(action) <= 1.0)


# ----------------------------------------------------------------------------------------- the sweep file
@pytest.mark.parametrize(("entries", "named"), [
    ({"learning_rat": 0.001}, "learning_rat"),
    ({"search": {"learning_rat": {"choice": [1e-3]}}}, "learning_rat"),
    ({"search": {"env_kwargs.max_tlt": {"choice": [0.1]}}}, "max_tlt"),
    ({"search": {"env_kwargs.randomization.noise": {"choice": [[0, 1]]}}}, "noise"),
    ({"search": {"learning_rate": {"uniform": [0.01, 0.001]}}}, "search.learning_rate"),
    ({"search": {"learning_rate": {"loguniform": [0.0, 0.001]}}}, "search.learning_rate"),
    ({"search": {"learning_rate": {"loguniform": [1e-4, float("inf")]}}}, "search.learning_rate"),
    ({"search": {"n_steps": {"grid": []}}}, "search.n_steps"),
    ({"search": {"n_steps": {"range": [1, 2]}}}, "search.n_steps"),
    ({"search": {"n_steps": [256, 512]}}, "search.n_steps"),
    ({"searcher": "optuna", "search": {"n_steps": {"grid": [256, 512]}}}, "n_steps"),
    ({"searcher": "hyperopt"}, "searcher"),
    ({"seeds": [0, 0]}, "seeds"),
    ({"seeds": [-1]}, "seed"),
    ({"n_timesteps": 0}, "n_timesteps"),
    ({"env": "StewartBallJuggle-v0"}, "env"),
    ({"algo": "a2c"}, "algo"),
    ({"geometry": "no-such-preset"}, "no-such-preset"),
    ({"eval_freq": 10**9}, "eval_freq"),
    ({"n_envs": 300}, "n_envs: at most 256 copies"),  # engines; the batched backend takes thousands
    # what train refuses, refused here before Ray starts (the trial's recipe checks, and one env built)
    ({"seeds": [2**40]}, "each seed must be at most"),
    ({"eval_episodes": 10**9}, "eval_episodes must be a whole number from 1 to 10,000"),
    ({"batch_size": 1}, "batch_size must be 2 or more"),
    ({"policy_kwargs": {"net_arch": [8], "bogus": 1}}, "policy_kwargs.bogus is not taken for PPO"),
    ({"env_kwargs": {"rate_penalty": -1.0}}, "rate_penalty must be ≥ 0"),
    ({"search": {"env_kwargs.rate_penalty": {"choice": [0.0, -1.0]}}}, "search.env_kwargs.rate_penalty = -1.0: the env of"),
    ({"search": {"ent_coef": {"choice": [0.0, "auto"]}}}, "search.ent_coef = 'auto': ppo.yml: ent_coef 'auto'"),
])  # fmt: skip
def test_a_malformed_sweep_file_is_refused_naming_the_key(tmp_path: Path, entries: dict, named: str) -> None:
    with pytest.raises(ConfigError, match=named.replace(".", r"\.")):
        load_sweep(write(tmp_path, **entries))


def test_the_sweep_file_is_read_into_fixed_and_searched_hyperparameters(tmp_path: Path) -> None:
    spec = load_sweep(write(tmp_path, seeds=[3, 4], env_kwargs={"max_tilt": 0.12}, search={
        "learning_rate": {"loguniform": [1e-4, 1e-3]}, "n_steps": {"grid": [256, 512]},
        "env_kwargs.rate_penalty": {"choice": [0.0, 0.1]},
        "env_kwargs.randomization.sensor_noise_mm": {"grid": [[0.5, 2.0], [0.5, 4.0]]}}))  # fmt: skip
    assert spec.trial_count() == 2 * 2 * 2  # grid points × seeds
    assert spec.fixed["n_steps"] == 256 and spec.fixed["env_kwargs"] == {"max_tilt": 0.12}
    sampled = {"learning_rate": 3e-4, "n_steps": 512, "env_kwargs.rate_penalty": 0.0,
               "env_kwargs.randomization.sensor_noise_mm": [0.5, 4.0]}  # fmt: skip
    hp = trial_overrides(spec, sampled)
    assert hp["learning_rate"] == 3e-4 and hp["n_steps"] == 512 and hp["batch_size"] == 64
    assert hp["env_kwargs"] == {"max_tilt": 0.12, "rate_penalty": 0.0, "randomization": {"sensor_noise_mm": [0.5, 4.0]}}


@pytest.mark.parametrize("name", ["ppo_balance", "ppo_batched"])
def test_the_shipped_sweep_files_load(name: str) -> None:
    spec = load_sweep(Path(__file__).resolve().parents[1] / "train" / "sweeps" / f"{name}.yaml")
    assert spec.trial_count() == {"ppo_balance": 24, "ppo_batched": 8}[name]
    assert spec.batched == (name == "ppo_batched") and spec.cpus_per_trial == 1


def test_trials_rank_finished_first_then_by_the_metric_and_configs_pool_seeds() -> None:
    spec = SweepSpec(env="StewartBallBalance-v0", algo="ppo", n_timesteps=10, search={"lr": ("grid", [1, 2])})
    trials = [{"trial": "a", "status": "finished", "lr": 1, "success_rate": 0.5, "mean_reward": 10},
              {"trial": "b", "status": "error", "lr": 2, "success_rate": None, "mean_reward": None},
              {"trial": "c", "status": "finished", "lr": 2, "success_rate": 0.9, "mean_reward": 5},
              {"trial": "d", "status": "stopped early", "lr": 1, "success_rate": 1.0, "mean_reward": 50},
              {"trial": "e", "status": "finished", "lr": 1, "success_rate": 0.5, "mean_reward": 20},
              {"trial": "f", "status": "finished", "lr": 2, "success_rate": 0.7, "mean_reward": 1}]  # fmt: skip
    assert [r["trial"] for r in rank_trials(spec, trials)] == ["c", "f", "e", "a", "d", "b"]
    configs = summarise_configs(spec, trials)
    assert [c["lr"] for c in configs] == [2, 1]
    assert configs[0]["seeds"] == 2 and configs[0]["success_rate_mean"] == pytest.approx(0.8)
    assert (configs[1]["success_rate_min"], configs[1]["mean_reward_max"]) == (0.5, 20)


@pytest.mark.slow
def test_the_cli_refuses_a_bad_sweep_in_one_line_before_ray_starts(tmp_path: Path) -> None:
    path = write(tmp_path, search={"env_kwargs.max_tlt": {"uniform": [0.1, 0.2]}})
    proc = sg("sweep", str(path), "--out", str(tmp_path / "out"), cwd=tmp_path)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 1 and len(lines) == 1 and lines[0].startswith("error:") and "max_tlt" in lines[0]
    assert not (tmp_path / "out").exists()
    proc = sg("sweep", str(write(tmp_path)), "--address", "127.0.0.1:9", "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert proc.returncode == 1 and "nothing answers there" in proc.stderr and "Traceback" not in proc.stderr


def test_a_sweep_on_the_batched_backend_takes_one_cpu_a_trial(tmp_path: Path) -> None:
    """A trial's copies on the batched backend step in its own process: one CPU, whatever n_envs; the
    recipe's copies when the file gives none; the backend itself is not swept."""
    path = tmp_path / "batched.yaml"
    path.write_text(yaml.safe_dump({k: v for k, v in {**TINY, "hyperparams": "ppo_batched"}.items() if k != "n_envs"}))
    spec = load_sweep(path)
    assert spec.batched and spec.n_envs == 128 and spec.cpus_per_trial == 1
    spec = load_sweep(write(tmp_path, n_envs=4, env_kwargs={"backend": "batched"}))
    assert spec.batched and spec.n_envs == 4 and spec.cpus_per_trial == 1
    spec = load_sweep(write(tmp_path, n_envs=2))
    assert not spec.batched and spec.cpus_per_trial == 2
    with pytest.raises(ConfigError, match="env_kwargs.backend"):
        load_sweep(write(tmp_path, search={"env_kwargs.backend": {"grid": ["batched", "pybullet"]}}))


# ----------------------------------------------------------------------------------------- real sweeps
def local_sweep(tmp_path: Path, **entries: object) -> tuple[Path, str, list[dict[str, str]]]:
    """``stewart-gym sweep`` of TINY with ``entries`` on a local Ray, which must exit 0: its --out folder, its
    stdout and its results table."""
    out = tmp_path / "out"
    proc = sg("sweep", str(write(tmp_path, **entries)), "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Token authentication" not in proc.stderr, proc.stderr  # Ray's own notice (the sweep sets its mode)
    return out, proc.stdout, rows(out)


@pytest.mark.slow
def test_a_local_rays_trials_run_at_the_sweeps_priority_unless_the_user_sets_another() -> None:
    """Ray's workers run 15 nice levels below their raylet by default, where any busy process starves them; the Ray
    a sweep starts runs them at the sweep's own priority, and ``RAY_worker_niceness`` levels below it when the user
    sets it (capped at 19: a suite run under ``nice`` gives the same verdict)."""
    code = ("import os, ray\nfrom stewart_gym.sweep import connect\n"
            "nice = ray.remote(lambda: os.nice(0))\n"
            "connect(None)\nprint(os.nice(0), ray.get(nice.remote()))\nray.shutdown()\n"
            "os.environ['RAY_worker_niceness'] = '7'\nconnect(None)\nprint(ray.get(nice.remote()))\n")  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "RAY_worker_niceness"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    own, worker, chosen = map(int, proc.stdout.split()[-3:])
    assert worker == own and chosen == min(19, own + 7), (own, worker, chosen)


@pytest.mark.slow
def test_a_local_sweep_reports_a_failed_trial_and_carries_on(tmp_path: Path) -> None:
    """Two trials on a local Ray: one finishes, one comes apart (a value loss weighted 1e300 turns the network
    to NaN, which no check of the file can foresee); the sweep ends normally, the table says which failed and why,
    and the finished trial's bundle is exported and deploys."""
    out, stdout, table = local_sweep(tmp_path, search={"vf_coef": {"grid": [0.5, 1e300]}})
    assert "1 finished, 0 stopped early by the scheduler, 1 failed" in stdout
    assert [r["status"] for r in table] == ["finished", "error"]
    assert float(table[0]["vf_coef"]) == 0.5 and int(table[0]["timesteps"]) >= 1024
    assert "training diverged" in table[1]["error"]
    run = Path(table[0]["run_dir"])
    for name in ("model.zip", "vecnormalize.pkl", "metrics.json", "eval.csv", "config.yaml", "bundle/bundle.json"):
        assert (run / name).is_file(), name
    assert yaml.safe_load((run / "config.yaml").read_text())["hyperparams"]["vf_coef"] == 0.5
    assert (out / "configs.csv").is_file() and (out / "sweep.png").stat().st_size > 1000
    check_bundle_deploys(out / "best_bundle")


@pytest.mark.slow
def test_a_local_sweep_on_the_batched_backend_runs_a_trial_per_cpu(tmp_path: Path) -> None:
    """Two trials of 4 copies each on the batched backend, side by side on 2 CPUs; both finish, trained on the
    batched backend, and the best bundle deploys."""
    out, stdout, table = local_sweep(tmp_path, n_envs=4, n_steps=64, env_kwargs={"backend": "batched"},
                                     search={"learning_rate": {"grid": [0.0003, 0.001]}})  # fmt: skip
    assert "1 CPU(s) each (4 copies on the batched backend)" in stdout
    assert [r["status"] for r in table] == ["finished", "finished"]
    for row in table:
        config = yaml.safe_load((Path(row["run_dir"]) / "config.yaml").read_text())
        assert config["hyperparams"]["env_kwargs"]["backend"] == "batched" and int(row["timesteps"]) >= 1024
    check_bundle_deploys(out / "best_bundle")


@pytest.mark.slow
def test_a_sweep_runs_on_a_two_node_cluster_with_address(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A head and a worker node (1 CPU each) on this machine; the sweep joins with --address, and its 4 trials
    run on both nodes (each takes 1 CPU: n_envs 1), all results come back, and the best bundle deploys."""
    from ray.cluster_utils import Cluster

    monkeypatch.setenv("RAY_worker_niceness", "0")  # the nodes' workers at the tests' priority, as a local sweep's
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "object_store_memory": 80 * 1024**2})
    try:
        cluster.add_node(num_cpus=1, object_store_memory=80 * 1024**2)
        cluster.wait_for_nodes()
        nodes = {n.node_id for n in cluster.list_all_nodes()}
        assert len(nodes) == 2
        path = write(tmp_path, seeds=[0, 1], search={"learning_rate": {"grid": [3e-4, 1e-3]}})
        out = tmp_path / "out"
        proc = sg("sweep", str(path), "--address", cluster.address, "--out", str(out), cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert "Ray: 2 node(s), 2 CPUs; 4 trial(s)" in proc.stdout
    finally:
        cluster.shutdown()
    table = rows(out)
    assert len(table) == 4 and all(r["status"] == "finished" for r in table)
    assert {(float(r["learning_rate"]), int(r["seed"])) for r in table} == {(a, s) for a in (3e-4, 1e-3) for s in (0, 1)}
    assert {r["node_id"] for r in table} == nodes  # both nodes trained
    assert all(np.isfinite(float(r["mean_reward"])) for r in table)
    check_bundle_deploys(out / "best_bundle")


@pytest.mark.slow
def test_an_interrupted_sweep_resumes_without_losing_finished_trials(tmp_path: Path) -> None:
    """Ctrl-C after two of four trials (one at a time): exit 130 and a line saying how to resume; --resume
    runs the rest and keeps the finished trials as they were (not retrained)."""
    path = write(tmp_path, seeds=[0, 1], search={"learning_rate": {"grid": [3e-4, 1e-3]}})
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "stewart_gym", "sweep", str(path), "--out", str(out), "--max-concurrent", "1"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while len(list(out.glob("trials/*"))) < 3 and time.monotonic() < deadline:  # the third trial has started
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-3000:]
    assert "--resume" in err.splitlines()[-1] and err.splitlines()[-1].startswith("error: interrupted")
    done = {r["trial"]: os.stat(Path(r["run_dir"]) / "metrics.json").st_mtime_ns
            for r in rows(out) if r["status"] == "finished"}  # fmt: skip
    assert len(done) == 2
    resumed = sg("sweep", str(path), "--out", str(out), "--max-concurrent", "1", "--resume", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    table = rows(out)
    assert len(table) == 4 and all(r["status"] == "finished" for r in table)
    for trial, mtime in done.items():
        row = next(r for r in table if r["trial"] == trial)
        assert os.stat(Path(row["run_dir"]) / "metrics.json").st_mtime_ns == mtime  # kept, not trained again
    proc = sg("sweep", str(path), "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 1 and "already holds a sweep" in proc.stderr
    changed = write(tmp_path, "changed.yaml", seeds=[0, 1], n_timesteps=2048,
                    search={"learning_rate": {"grid": [3e-4, 1e-3]}})  # fmt: skip
    proc = sg("sweep", str(changed), "--out", str(out), "--resume", cwd=tmp_path)
    assert proc.returncode == 1 and "n_timesteps" in proc.stderr and "differ from" in proc.stderr


@pytest.mark.slow
def test_an_optuna_sweep_samples_each_configuration_once_per_seed(tmp_path: Path) -> None:
    """searcher optuna: 2 sampled configurations × 2 seeds = 4 trials; each configuration is trained with both
    seeds (Ray's Repeater), its values inside the ranges."""
    path = write(tmp_path, seeds=[0, 1], searcher="optuna", num_samples=2, scheduler="fifo", search={
        "learning_rate": {"loguniform": [1e-4, 1e-3]}, "env_kwargs.rate_penalty": {"uniform": [0.0, 1.0]}})
    out = tmp_path / "out"
    proc = sg("sweep", str(path), "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    table = rows(out)
    assert len(table) == 4 and all(r["status"] == "finished" for r in table)
    configs: dict[tuple, set] = {}
    for r in table:
        lr, penalty = float(r["learning_rate"]), float(r["env_kwargs.rate_penalty"])
        assert 1e-4 <= lr <= 1e-3 and 0.0 <= penalty <= 1.0
        configs.setdefault((lr, penalty), set()).add(int(r["seed"]))
    assert len(configs) == 2 and all(seeds == {0, 1} for seeds in configs.values())
