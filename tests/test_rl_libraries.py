"""The envs and recipes under the RL libraries our users already run: RL Zoo (``-conf`` our hyperparameter files),
TorchRL (``GymEnv``, its spec check, the example) and RLlib (the example). Each is driven as its users drive it."""

from __future__ import annotations

import inspect
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from conftest import load_example, sg_in
from rl_zoo3.utils import get_wrapper_class
from sb3_contrib import TQC
from stable_baselines3 import PPO, SAC, TD3

import stewart_gym  # noqa: F401  (registers the env ids)
from stewart_gym.errors import ConfigError
from stewart_gym.sb3_models import ResidualAction
from stewart_gym.training import EVALUATION_SECTION, HYPERPARAM_DIR, load_hyperparams

ROOT = Path(__file__).resolve().parents[1]
RECIPES = sorted(HYPERPARAM_DIR.glob("*.yml"))
ALGO_OF_RECIPE = {"ppo": PPO, "sac": SAC, "td3": TD3, "tqc": TQC}
#: The keys that RL Zoo's ExperimentManager takes out of a section before it calls the algorithm with the rest.
RL_ZOO_KEYS = {"n_envs", "n_timesteps", "normalize", "normalize_kwargs", "policy", "env_kwargs", "env_wrapper",
               "vec_env_wrapper", "callback", "frame_stack", "monitor_kwargs", "noise_type", "noise_std"}


def sections(path: Path) -> dict[str, dict]:
    return {k: v for k, v in yaml.safe_load(path.read_text()).items() if k != EVALUATION_SECTION}


@pytest.mark.parametrize("path", RECIPES, ids=[p.stem for p in RECIPES])
def test_every_recipe_section_is_what_rl_zoo_passes_to_the_algorithm(path: Path) -> None:
    """What RL Zoo leaves of each section is a keyword of the algorithm's constructor, and every section's env id
    is registered (``python -m rl_zoo3.train -conf`` would otherwise fail as ``eval_freq`` once did)."""
    algo = ALGO_OF_RECIPE[path.stem.split("_")[0]]
    accepted = set(inspect.signature(algo.__init__).parameters)
    for env_id, section in sections(path).items():
        assert env_id in gym.registry, (path.name, env_id)
        assert not (set(section) - RL_ZOO_KEYS - accepted), (path.name, env_id, set(section) - RL_ZOO_KEYS - accepted)


def test_rl_zoo_builds_the_residual_wrapper_that_train_builds() -> None:
    """RL Zoo's own ``get_wrapper_class`` reads the residual recipe's ``env_wrapper`` into our ResidualAction, with
    the settings that ``load_hyperparams`` gives ``stewart-gym train``."""
    actions = np.random.default_rng(0).uniform(-1, 1, size=(40, 2)).astype(np.float32)
    for env_id, section in sections(HYPERPARAM_DIR / "ppo_residual.yml").items():
        zoo = get_wrapper_class(section)(gym.make(env_id, **section["env_kwargs"]))
        ours = ResidualAction(gym.make(env_id, **section["env_kwargs"]),
                              load_hyperparams("ppo", env_id, "ppo_residual")["residual"])
        try:
            assert isinstance(zoo, ResidualAction)
            (a, _), (b, _) = zoo.reset(seed=3), ours.reset(seed=3)
            for action in actions:
                a, *_ = zoo.step(action)
                b, *_ = ours.step(action)
                np.testing.assert_array_equal(a, b)
            assert np.all(np.isfinite(a))
        finally:
            zoo.close()
            ours.close()


@pytest.mark.parametrize(("text", "match"), [
    ("S:\n  n_timesteps: 10\n  eval_freq: 5\n", r"S\.eval_freq: RL Zoo would pass it .* evaluation: section"),
    ("S:\n  n_timesteps: 10\n  eval_episodes: 5\n", r"S\.eval_episodes: .* \(evaluation: \{S: \{eval_episodes: …\}\}\)"),
    ("S:\n  n_timesteps: 10\n  residual: {base: lqr}\n", r"S\.residual: .* env_wrapper: \{stewart_gym\.sb3_models"),
    ("S:\n  env_wrapper: gymnasium.wrappers.TimeAwareObservation\n", r"S\.env_wrapper: the one wrapper a recipe"),
    ("S:\n  env_wrapper: {stewart_gym.sb3_models.ResidualAction: {base: lqr}}\n", r"S\.env_wrapper: the one"),
    ("S: {n_timesteps: 10}\nevaluation: {S: {eval_freq: 5, eval_every: 3}}\n", r"evaluation\.S: unknown keys \['eval"),
    ("S: {n_timesteps: 10}\nevaluation: [1, 2]\n", r"evaluation must map env ids"),
    ("S: {n_timesteps: 10}\nevaluation: {S: {eval_freq: 0}}\n", r"S\.eval_freq must be a number ≥ 1"),
])  # fmt: skip
def test_a_recipe_in_a_shape_rl_zoo_cannot_load_is_refused_saying_where_each_setting_goes(
        tmp_path: Path, text: str, match: str) -> None:  # fmt: skip
    path = tmp_path / "hp.yml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match):
        load_hyperparams("ppo", "S", path)


def test_the_evaluation_section_and_the_wrapper_come_back_as_train_settings(tmp_path: Path) -> None:
    path = tmp_path / "hp.yml"
    path.write_text("S:\n  n_timesteps: 10\n  env_wrapper:\n    - stewart_gym.sb3_models.ResidualAction:\n"
                    "        residual: {base: lqr, scale: 0.5}\nT: {n_timesteps: 10}\n"
                    "evaluation: {S: {eval_freq: 7, eval_episodes: 3}}\n")  # fmt: skip
    assert load_hyperparams("ppo", "S", path) == {"n_timesteps": 10, "residual": {"base": "lqr", "scale": 0.5},
                                                  "eval_freq": 7, "eval_episodes": 3}  # fmt: skip
    assert load_hyperparams("ppo", "T", path) == {"n_timesteps": 10}
    with pytest.raises(ConfigError, match=r"no section for 'U' \(sections: \['S', 'T'\]\)"):
        load_hyperparams("ppo", "U", path)


@pytest.mark.slow
@pytest.mark.parametrize("recipe", ["ppo", "ppo_residual"])
def test_rl_zoo_trains_a_shipped_recipe(recipe: str, tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """``python -m rl_zoo3.train -conf`` one of our files, as the RL Zoo documents it: a model and its
    normalisation statistics, which SB3 loads and steps the env with."""
    proc = subprocess.run(
        [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", "StewartBallBalance-v0",
         "--gym-packages", "stewart_gym", "-conf", str(HYPERPARAM_DIR / f"{recipe}.yml"), "-n", "2048",
         "--eval-freq", "1024", "--eval-episodes", "1", "-f", str(tmp_path), "--seed", "0", "--device", "cpu",
         "--n-eval-envs", "1"],
        capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "ppo" / "StewartBallBalance-v0_1"
    assert (run / "StewartBallBalance-v0.zip").exists() and (run / "StewartBallBalance-v0" / "vecnormalize.pkl").exists()
    model = PPO.load(run / "StewartBallBalance-v0.zip", device="cpu")
    assert model.num_timesteps >= 2048 and model.observation_space.shape == (12,)  # one rollout of the recipe's
    # stewart-gym does not read RL Zoo's settings, and says so rather than run the model without them
    proc = sg_in(capfd, "evaluate", "--policy", str(run / "StewartBallBalance-v0.zip"), "--episodes", "1")
    assert proc.returncode == 1 and "is an RL Zoo model" in proc.stderr and "rl_zoo3.enjoy" in proc.stderr, proc.stderr


def test_torchrl_gym_env_passes_its_spec_check_with_the_info_entries() -> None:
    """TorchRL's ``GymEnv`` by id (it probes keywords such as ``frameskip``: a TypeError, not ours), its
    ``check_env_specs``, and ``auto_register_info_dict``: every info entry a key of the step, ``is_success`` a bool."""
    import torch
    from torchrl.envs import GymEnv
    from torchrl.envs.utils import check_env_specs

    env = GymEnv("StewartBallBalance-v0")
    try:
        env.auto_register_info_dict()
        env.set_seed(0)
        check_env_specs(env)
        torch.manual_seed(0)  # the rollout's random actions; full tilts can drop the ball, and the rollout goes on
        rollout = env.rollout(30, break_when_any_done=False)
        assert rollout["next", "observation"].shape == (30, 12) and rollout["action"].shape == (30, 2)
        assert rollout["next", "is_success"].dtype == torch.bool
        assert rollout["next", "distance_mm"].shape == (30,) and torch.all(rollout["next", "distance_mm"] >= 0)
    finally:
        env.close()


@pytest.mark.slow
def test_torchrl_example_trains_and_evaluates(capsys: pytest.CaptureFixture) -> None:
    load_example("torchrl_ppo").main(["--frames", "1024", "--batch", "512", "--episodes", "1"])
    out = capsys.readouterr().out.splitlines()
    assert out[:2] == [line for line in out if line.startswith("frames")] and len(out) == 3
    assert out[0].startswith("frames 512: mean reward ") and out[1].startswith("frames 1024: mean reward ")
    assert out[2] in ("success 0/1", "success 1/1")


@pytest.mark.slow
def test_rllib_example_trains_and_evaluates(capsys: pytest.CaptureFixture) -> None:
    load_example("rllib_ppo").main(["--iterations", "1", "--batch", "500", "--episodes", "1"])
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("iteration 1: mean episode return ") and out[-1] in ("success 0/1", "success 1/1")


@pytest.mark.parametrize(("example", "name"), [("torchrl_ppo", "setup"), ("rllib_ppo", "config")])
def test_the_libraries_page_shows_the_examples_code_as_it_is(example: str, name: str) -> None:
    """docs/src/libraries.md holds each example's marked lines in a code block, the same to the character."""
    text = (ROOT / "examples" / f"{example}.py").read_text()
    start = re.search(rf"\n( *)# docs: {name} start[^\n]*\n", text)
    end = text.index(f"{start.group(1)}# docs: {name} end\n")
    code = textwrap.dedent(text[start.end():end])
    assert len(code.splitlines()) >= 8
    assert f"```python\n{code}```\n" in (ROOT / "docs" / "src" / "libraries.md").read_text(), \
        f"docs/src/libraries.md no longer shows examples/{example}.py's {name} lines as they are"  # fmt: skip
