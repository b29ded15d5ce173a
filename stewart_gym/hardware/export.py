"""Policy bundles for deployment: ONNX + JSON, run with onnxruntime and numpy (no torch, no pickle).

A bundle is a folder with ``bundle.json`` and, for a learned policy,
``policy.onnx``. ``bundle.json`` holds the kind (``"onnx"`` or ``"pid"``), the
env id and action mode, the observation normalisation (VecNormalize mean, var,
clip, epsilon) and the action bounds. The ONNX graph maps a *normalised*
observation to the deterministic action (PPO: the Gaussian mean; SAC/TD3: the
actor's output) *before* clipping, as Stable-Baselines3's export guide
describes; :class:`BundlePolicy` normalises and clips around it exactly as
``model.predict(deterministic=True)`` does.

Exporting needs torch (training side); loading needs onnxruntime only.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["BundlePolicy", "export_pid", "export_sb3"]


def export_sb3(model_path: str | Path, out_dir: str | Path, env_id: str = "StewartBallBalance-v0",
               action_mode: str = "tilt") -> Path:  # fmt: skip
    """Export an SB3 model folder/zip (with its ``vecnormalize.pkl``) to a bundle in ``out_dir``."""
    import torch
    from stable_baselines3 import PPO, SAC

    from stewart_gym.evaluation import load_sb3

    sb3 = load_sb3(model_path)
    model = sb3.model
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    class _Deterministic(torch.nn.Module):
        """Normalised observation → deterministic action, before clipping (SB3's predict, minus the clip)."""

        def __init__(self) -> None:
            super().__init__()
            self.policy = model.policy if isinstance(model, PPO) else model.policy.actor

        def forward(self, obs: torch.Tensor) -> torch.Tensor:
            p = self.policy
            if isinstance(model, PPO):  # the Gaussian's mean
                return p.action_net(p.mlp_extractor.forward_actor(p.extract_features(obs, p.pi_features_extractor)))
            if isinstance(model, SAC):  # tanh-squashed mean
                return p(obs, deterministic=True)
            return p(obs)  # TD3: tanh output

    net = _Deterministic().eval()
    n_obs = int(model.observation_space.shape[0])
    with torch.no_grad():
        torch.onnx.export(net, torch.zeros(1, n_obs), str(out / "policy.onnx"), input_names=["obs"],
                          output_names=["action"], dynamic_axes={"obs": {0: "batch"}, "action": {0: "batch"}},
                          dynamo=False)  # fmt: skip
    meta: dict[str, Any] = {
        "kind": "onnx",
        "env_id": env_id,
        "action_mode": action_mode,
        "algo": type(model).__name__.lower(),
        "obs_size": n_obs,
        "action_low": model.action_space.low.tolist(),
        "action_high": model.action_space.high.tolist(),
        "obs_mean": None if sb3.obs_rms is None else sb3.obs_rms.mean.tolist(),
        "obs_var": None if sb3.obs_rms is None else sb3.obs_rms.var.tolist(),
        "clip_obs": sb3.clip_obs,
        "epsilon": sb3.epsilon,
    }
    (out / "bundle.json").write_text(json.dumps(meta, indent=2) + "\n")
    return out


def export_pid(gains_path: str | Path, out_dir: str | Path, env_id: str = "StewartBallBalance-v0") -> Path:
    """Export the PID baseline's gains to a bundle (``kind: "pid"``)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    gains = json.loads(Path(gains_path).read_text())
    (out / "bundle.json").write_text(json.dumps({"kind": "pid", "env_id": env_id, "action_mode": "tilt",
                                                 "gains": gains}, indent=2) + "\n")  # fmt: skip
    return out


class BundlePolicy:
    """A policy from a bundle folder, for deployment: onnxruntime + numpy only."""

    def __init__(self, bundle_dir: str | Path) -> None:
        folder = Path(bundle_dir)
        meta_path = folder / "bundle.json"
        if not meta_path.exists():
            raise FileNotFoundError(f"{folder} is not a policy bundle (no bundle.json)")
        self.meta = json.loads(meta_path.read_text())
        self.kind = self.meta["kind"]
        self.action_mode = self.meta.get("action_mode", "tilt")
        if self.kind == "pid":
            from stewart_gym.controllers import CascadedPID, PIDGains

            self._pid = CascadedPID(PIDGains(**self.meta["gains"]))
            return
        if self.kind != "onnx":
            raise ValueError(f"{meta_path}: unknown kind {self.kind!r}")
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        self._session = ort.InferenceSession(str(folder / "policy.onnx"), opts, providers=["CPUExecutionProvider"])
        self._mean = None if self.meta["obs_mean"] is None else np.asarray(self.meta["obs_mean"], np.float64)
        var = self.meta["obs_var"]
        self._std = None if var is None else np.sqrt(np.asarray(var, np.float64) + self.meta["epsilon"])
        self._clip = float(self.meta["clip_obs"])
        self._low = np.asarray(self.meta["action_low"], np.float32)
        self._high = np.asarray(self.meta["action_high"], np.float32)

    def reset(self) -> None:
        """Start of an episode (clears the PID integrator)."""
        if self.kind == "pid":
            self._pid.reset()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Action(s) for observation(s) (…, obs_size), clipped to the action bounds."""
        if self.kind == "pid":
            return self._pid(obs)
        o = np.asarray(obs, dtype=np.float64)
        if self._mean is not None:
            o = np.clip((o - self._mean) / self._std, -self._clip, self._clip)
        x = o.astype(np.float32).reshape(-1, o.shape[-1])
        action = self._session.run(None, {"obs": x})[0]
        return np.clip(action, self._low, self._high).reshape(*o.shape[:-1], -1)

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:  # fmt: skip
        """Stable-Baselines3-style ``predict`` (so :func:`~stewart_gym.evaluation.evaluate` runs bundles too)."""
        if episode_start is not None and np.any(episode_start):
            self.reset()
        return self(obs), None
