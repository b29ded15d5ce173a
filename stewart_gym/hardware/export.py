"""Policy bundles for deployment: ONNX + JSON, run with onnxruntime and numpy (no torch, no pickle).

A bundle is a folder with ``bundle.json`` and, for a learned policy,
``policy.onnx``. ``bundle.json`` holds the kind (``"onnx"``, ``"pid"`` or ``"lqr"``),
the env id and action mode, the observer (``estimator``), the observation normalisation (VecNormalize mean, var,
clip, epsilon) and the action bounds. The ONNX graph maps a *normalised*
observation to the deterministic action (PPO: the Gaussian mean; SAC/TQC/TD3: the
actor's output) *before* clipping, as Stable-Baselines3's export guide
describes; :class:`BundlePolicy` normalises and clips around it exactly as
``model.predict(deterministic=True)`` does.

Exporting needs torch (training side); loading needs onnxruntime only.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.actions import ACTION_SIZES, DEFAULT_MAX_TILT
from stewart_gym.control import (
    CLASSICAL_KINDS,
    ResidualMix,
    bounded,
    checked_design,
    controller_from_gains,
    design_estimator,
)
from stewart_gym.errors import PolicyError
from stewart_gym.inputs import read_json
from stewart_gym.sensing import ESTIMATORS, ObservationBuilder

__all__ = ["BUNDLE_FIELDS", "BundlePolicy", "bundle_geometry", "classical_meta", "export_bundle_copy", "export_pid",
           "export_sb3"]  # fmt: skip

#: The fields a ``bundle.json`` may hold (what :func:`export_sb3`, :func:`export_pid` and
#: :func:`classical_meta` write); any other is refused as a sign of an edited or foreign file.
BUNDLE_FIELDS = ("kind", "env_id", "env_kwargs", "action_mode", "algo", "obs_size", "action_low", "action_high",
                 "obs_mean", "obs_var", "clip_obs", "epsilon", "ensemble", "residual", "gains", "geometry",
                 "control_hz", "max_tilt", "observation_layout", "estimator", "integral")  # fmt: skip



def export_sb3(model_path: str | Path, out_dir: str | Path, env_id: str = "StewartBallBalance-v0",
               env_kwargs: dict[str, Any] | None = None) -> Path:  # fmt: skip
    """Export an SB3 model folder/zip (with its ``vecnormalize.pkl``), or an ensemble folder, to a bundle in
    ``out_dir``.

    ``env_kwargs`` are the env keywords the model was trained with that define
    its observation and action (``action_mode``, ``max_tilt``, ``control_hz``,
    and the track's ``trajectory``); they go into ``bundle.json``. An ensemble's graph holds every network with
    its own normalisation and clipping, and outputs their mean (``bundle.json``: ``ensemble`` N, no
    ``obs_mean``); a single network's graph takes the normalised observation.
    """
    import torch

    from stewart_gym.sb3_models import EnsemblePolicy, deterministic_module, load_learned

    learned = load_learned(model_path)
    ensemble = isinstance(learned, EnsemblePolicy)
    members = learned.members if ensemble else [learned]
    model = members[0].model
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    net = learned.module if ensemble else deterministic_module(model).eval()
    n_obs = int(model.observation_space.shape[0])
    # torch's current exporter (torch.export, with onnxscript): the same outputs, to the last bit, as the
    # TorchScript one it replaces, for the shipped policies; its progress lines are kept off the user's screen. The
    # weights go inside policy.onnx (external_data=False: no policy.onnx.data beside it), so that the bundle is the
    # two files the docs name, whatever copies it
    with torch.no_grad(), quiet_exporter():
        torch.onnx.export(net, (torch.zeros(1, n_obs),), str(out / "policy.onnx"), input_names=["obs"],
                          output_names=["action"], dynamic_shapes=({0: torch.export.Dim("batch")},), dynamo=True,
                          external_data=False, verbose=False)  # fmt: skip
    (out / "policy.onnx.data").unlink(missing_ok=True)  # an earlier export's weights, which nothing reads now
    sb3 = members[0]
    env_kwargs = dict(env_kwargs or {})
    action_mode = str(env_kwargs.get("action_mode", "tilt"))
    if int(model.action_space.shape[0]) != ACTION_SIZES.get(action_mode, -1):
        raise PolicyError(f"{model_path}: {model.action_space.shape[0]} actions do not fit action_mode {action_mode!r}")
    meta: dict[str, Any] = {
        "kind": "onnx",
        "env_id": env_id,
        "action_mode": action_mode,
        "env_kwargs": env_kwargs,
        "algo": type(model).__name__.lower(),
        "obs_size": n_obs,
        "action_low": model.action_space.low.tolist(),
        "action_high": model.action_space.high.tolist(),
        "obs_mean": None if ensemble or sb3.obs_rms is None else sb3.obs_rms.mean.tolist(),
        "obs_var": None if ensemble or sb3.obs_rms is None else sb3.obs_rms.var.tolist(),
        "clip_obs": sb3.clip_obs,
        "epsilon": sb3.epsilon,
        **build_meta(env_kwargs.get("geometry", "servo-hexapod"), env_kwargs),
    }
    if ensemble:  # the graph normalises each network's input itself
        meta["ensemble"] = len(members)
    if env_kwargs.get("residual"):  # the network's action corrects a classical controller's: record that one
        from stewart_gym.control import CLASSICAL
        from stewart_gym.sb3_models import check_residual, residual_base

        spec = check_residual(env_kwargs["residual"], recorded=True)
        geometry = env_kwargs.get("geometry", "servo-hexapod")
        base = residual_base(spec, geometry, dt=1.0 / meta["control_hz"])  # designed for the period it runs at
        meta["residual"] = {"scale": spec["scale"], "fade_mm": spec["fade_mm"], "inner_mm": spec["inner_mm"],
                            "release_mm": spec["release_mm"], "dwell_s": spec.get("dwell_s", 0.0),
                            "base": classical_meta(CLASSICAL[spec["base"]][0], asdict(base.gains), env_id, geometry,
                                                   meta["estimator"])}  # fmt: skip
    (out / "bundle.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    return out


@contextlib.contextmanager
def quiet_exporter() -> Iterator[None]:
    """torch's ONNX exporter without its log lines and progress prints (to the logging module and stdout), and
    without the warnings torch raises about its own internals."""
    import logging
    import warnings

    loggers = [logging.getLogger(name) for name in ("torch.onnx", "torch.export", "torch._dynamo", "onnxscript")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
            warnings.filterwarnings("ignore", module=r"torch\.|onnxscript")
            for kind in (FutureWarning, DeprecationWarning):  # torch's notes to itself, from inside the export
                warnings.simplefilter("ignore", kind)
            yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def build_meta(geometry: Any, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """What a bundle records about the build and the env it was made for.

    The geometry (its name and its full TOML, so the robot's computer needs no
    preset or file), the control rate, the tilt scale and the observation
    layout version: deploy checks them before it opens the port.
    """
    from stewart_gym.actions import default_max_tilt
    from stewart_gym.presets import load_geometry
    from stewart_gym.sensing import ObservationBuilder

    geo = load_geometry(geometry)
    return {
        "geometry": {"name": geo.name, "toml": geo.to_toml()},
        "control_hz": int(env_kwargs.get("control_hz", 50)),
        "max_tilt": float(env_kwargs.get("max_tilt") or default_max_tilt(geo)),
        "observation_layout": ObservationBuilder.LAYOUT_VERSION,
        "estimator": str(env_kwargs.get("estimator", "lowpass")),
        "integral": bool(env_kwargs.get("integral", False)),
    }


def classical_meta(kind: str, gains: dict[str, Any], env_id: str = "StewartBallBalance-v0",
                   geometry: Any = "servo-hexapod", estimator: str = "lowpass") -> dict[str, Any]:  # fmt: skip
    """The ``bundle.json`` content of a classical controller (``kind`` ``"pid"`` or ``"lqr"``) with these gains,
    for ``geometry``, behind the observer ``estimator``."""
    gains = {k: list(v) if isinstance(v, tuple) else v for k, v in gains.items()}
    meta = {"kind": kind, "env_id": env_id, "action_mode": "tilt", "obs_size": 12, "gains": gains,
            **build_meta(geometry, {"max_tilt": gains.get("max_tilt"), "estimator": estimator})}  # fmt: skip
    meta["gains"] = {**gains, "max_tilt": meta["max_tilt"]}
    return meta


def export_pid(gains: str | Path | dict[str, Any], out_dir: str | Path, env_id: str = "StewartBallBalance-v0",
               geometry: Any = "servo-hexapod") -> Path:  # fmt: skip
    """Export the PID baseline's gains (a dict or a gains ``.json``, checked) to a bundle (``kind: "pid"``),
    behind the observer the gains name (``estimator``; the low-pass one if they name none)."""
    out = Path(out_dir)
    if isinstance(gains, dict):
        values = gains
    else:
        values = read_json(gains, "gains file", error=PolicyError)
    estimator = design_estimator(values) or "lowpass"  # the observer the gains name, else the plain PID's
    meta = classical_meta("pid", asdict(checked_design(values, "pid")), env_id, geometry, estimator)
    out.mkdir(parents=True, exist_ok=True)  # once the gains and the build are sound: a refusal leaves no folder
    (out / "bundle.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    return out


def export_bundle_copy(bundle_dir: str | Path, out_dir: str | Path) -> Path:
    """Copy a bundle folder (``bundle.json`` and ``policy.onnx``, and the ``policy.onnx.data`` that holds the
    weights of a bundle exported with them apart) to ``out_dir``; checked by loading it."""
    import shutil

    src, out = Path(bundle_dir), Path(out_dir)
    BundlePolicy(src)
    out.mkdir(parents=True, exist_ok=True)
    for name in ("bundle.json", "policy.onnx", "policy.onnx.data"):
        if (src / name).exists() and (src / name).resolve() != (out / name).resolve():
            shutil.copyfile(src / name, out / name)
    return out


#: Hz: the highest control rate a bundle may name (the deploy loop's own limit).
MAX_CONTROL_HZ = 500.0


def _number(meta: dict[str, Any], key: str, where: Path, default: float | None, lo: float, hi: float) -> float:
    """``meta[key]`` (or ``default`` when absent; None: required) as a finite number in [lo, hi]."""
    if key not in meta and default is not None:
        return float(default)
    value = meta.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and lo <= value <= hi):
        got = "missing" if key not in meta else repr(value)
        raise PolicyError(f"{where}: {key} must be a number in {lo:g}…{hi:g}, got {got}; re-export the policy")
    return float(value)


def _vector(meta: dict[str, Any], key: str, where: Path, size: int) -> np.ndarray | None:
    """``meta[key]``: None, or a list of ``size`` finite numbers."""
    value = meta[key]
    if value is None:
        return None
    if (not isinstance(value, list) or len(value) != size
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        if isinstance(value, list) and len(value) == size:
            bad = next(i for i, v in enumerate(value)
                       if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)))  # fmt: skip
            got = f"{key}[{bad}] is {value[bad]!r}"
        else:
            got = f"got {len(value) if isinstance(value, list) else type(value).__name__}"
        raise PolicyError(f"{where}: {key} must be {size} finite numbers (the observation or action size); {got}; "
                          "re-export the policy")  # fmt: skip
    return np.asarray(value, np.float64)


def bundle_geometry(meta: dict[str, Any], meta_path: Path) -> Any:
    """The geometry a bundle was made for: its embedded TOML, whose name must be the one the bundle gives (bundles
    without a geometry: the reference build). Raises :class:`PolicyError` naming ``meta_path``."""
    from stewart_gym.geometry import GeometryError, PlatformGeometry
    from stewart_gym.presets import check_home, load_preset
    from stewart_gym.tomlio import tomllib

    entry = meta.get("geometry")
    if entry is None:
        return load_preset("servo-hexapod")
    if not isinstance(entry, dict) or not isinstance(entry.get("toml"), str) or not isinstance(entry.get("name"), str):
        raise PolicyError(f"{meta_path}: geometry must be {{name, toml}}: the build's name and its whole geometry "
                          "file; re-export the policy")  # fmt: skip
    try:
        geometry = PlatformGeometry.from_dict(tomllib.loads(entry["toml"]), source=f"{meta_path} geometry")
        check_home(geometry, f"{meta_path} geometry")
    except tomllib.TOMLDecodeError as exc:
        raise PolicyError(f"{meta_path}: malformed geometry ({exc}); re-export the policy") from None
    except GeometryError as exc:
        raise PolicyError(f"{exc}; re-export the policy") from None
    if geometry.name != entry["name"]:
        raise PolicyError(f"{meta_path}: geometry.name {entry['name']!r} is not the name in geometry.toml "
                          f"({geometry.name!r}); re-export the policy")  # fmt: skip
    return geometry


class BundlePolicy:
    """A policy from a bundle folder, for deployment: onnxruntime + numpy only. Every field of ``bundle.json`` is
    checked as it loads (sizes, ranges, finite numbers), so a damaged bundle is refused before anything runs."""

    def __init__(self, bundle_dir: str | Path) -> None:
        folder = Path(bundle_dir)
        meta_path = folder / "bundle.json"
        if not meta_path.is_file():
            raise PolicyError(f"{folder} is not a policy bundle (no bundle.json); write one with stewart-gym export")
        meta = read_json(meta_path, "bundle description", error=PolicyError)
        self._setup(meta, folder, meta_path)

    @classmethod
    def from_meta(cls, meta: dict[str, Any]) -> BundlePolicy:
        """A bundle held in memory (the PID's: no file is written)."""
        self = cls.__new__(cls)
        self._setup(meta, None, Path("<memory>"))
        return self

    def _setup(self, meta: Any, folder: Path | None, meta_path: Path) -> None:
        if not isinstance(meta, dict) or meta.get("kind") not in ("onnx", *CLASSICAL_KINDS):
            kind = meta.get("kind") if isinstance(meta, dict) else None
            raise PolicyError(f"{meta_path}: unknown bundle kind {kind!r} (expected 'onnx', 'pid', 'lqr' or "
                              "'handover')")  # fmt: skip
        unknown = sorted(set(meta) - set(BUNDLE_FIELDS))
        if unknown:
            raise PolicyError(f"{meta_path}: unknown field(s) {unknown}; a bundle holds {', '.join(BUNDLE_FIELDS)}: "
                              "re-export the policy")  # fmt: skip
        self.meta = meta
        self.kind = meta["kind"]
        self.env_id = meta.get("env_id", "StewartBallBalance-v0")
        if not isinstance(self.env_id, str):
            raise PolicyError(f"{meta_path}: env_id must be an env id, got {self.env_id!r}; re-export the policy")
        self.action_mode = meta.get("action_mode", "tilt")
        if self.action_mode not in ACTION_SIZES:
            raise PolicyError(f"{meta_path}: action_mode must be one of {sorted(ACTION_SIZES)}, got {self.action_mode!r}")
        self.action_size = ACTION_SIZES[self.action_mode]
        hz = _number(meta, "control_hz", meta_path, 50, 1.0, MAX_CONTROL_HZ)
        if hz != int(hz):
            raise PolicyError(f"{meta_path}: control_hz must be a whole number of Hz, got {hz!r}")
        self.control_hz = int(hz)
        gains = meta.get("gains", {})
        tilt_default = gains.get("max_tilt", DEFAULT_MAX_TILT) if isinstance(gains, dict) else DEFAULT_MAX_TILT
        self.max_tilt = _number(meta, "max_tilt", meta_path, tilt_default, 1e-3, 1.0)
        #: the observation layout version it was made for (bundles older than the field: version 1)
        self.observation_layout = int(_number(meta, "observation_layout", meta_path, 1, 1, 1000))
        if self.observation_layout != ObservationBuilder.LAYOUT_VERSION:
            raise PolicyError(f"{meta_path}: the policy was exported for observation layout {self.observation_layout}; "
                              f"this version builds layout {ObservationBuilder.LAYOUT_VERSION}: re-export it")  # fmt: skip
        self.geometry = bundle_geometry(meta, meta_path)
        #: the observer it runs behind (bundles older than the field: the low-pass one)
        self.estimator = str(meta.get("estimator", "lowpass"))
        if self.estimator not in ESTIMATORS:
            raise PolicyError(f"{meta_path}: estimator must be one of {list(ESTIMATORS)}, got {self.estimator!r}")
        #: whether its observation ends with the error integral (bundles older than the field: no)
        self.integral = meta.get("integral", False)
        if not isinstance(self.integral, bool):
            raise PolicyError(f"{meta_path}: integral must be true or false, got {self.integral!r}")
        expected_obs = 10 + self.action_size + (2 if self.integral else 0)  # ObservationBuilder's layout
        if self.kind in CLASSICAL_KINDS:
            if self.action_mode != "tilt":
                raise PolicyError(f"{meta_path}: the {self.kind.upper()} commands tilt, not {self.action_mode!r}")
            width, depth = self.geometry.plate_extent
            try:
                self._classical: Any = controller_from_gains(self.kind, meta["gains"], (width / 2, depth / 2))
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                raise PolicyError(f"{meta_path}: malformed {self.kind.upper()} gains ({exc})") from None
            self.obs_size = 10 + self.action_size
            return
        missing = [k for k in ("obs_size", "action_low", "action_high", "obs_mean", "obs_var", "clip_obs", "epsilon")
                   if k not in meta]  # fmt: skip
        if missing:
            raise PolicyError(f"{meta_path}: missing field(s) {missing}; re-export the policy")
        self.obs_size = int(_number(meta, "obs_size", meta_path, None, 1, 10_000))
        if self.obs_size != expected_obs:
            raise PolicyError(f"{meta_path}: obs_size {meta['obs_size']!r}, but action_mode {self.action_mode!r}"
                              f"{' with the error integral' if self.integral else ''} observes {expected_obs} values; "
                              "re-export the policy")  # fmt: skip
        low = _vector(meta, "action_low", meta_path, self.action_size)
        high = _vector(meta, "action_high", meta_path, self.action_size)
        if low is None or high is None or not np.all(low < high):
            raise PolicyError(f"{meta_path}: action_low must be below action_high in every entry; re-export the policy")
        mean = _vector(meta, "obs_mean", meta_path, self.obs_size)
        var = _vector(meta, "obs_var", meta_path, self.obs_size)
        if (mean is None) != (var is None) or (var is not None and np.any(var < 0)):
            raise PolicyError(f"{meta_path}: obs_mean and obs_var go together, and a variance is ≥ 0; re-export the "
                              "policy")  # fmt: skip
        clip = _number(meta, "clip_obs", meta_path, None, 1e-6, 1e6)
        epsilon = _number(meta, "epsilon", meta_path, None, 1e-12, 1.0)  # (0: a division by zero where var is 0)
        if "ensemble" in meta:
            _number(meta, "ensemble", meta_path, None, 1, 1000)
        assert folder is not None
        onnx_path = folder / "policy.onnx"
        if not onnx_path.is_file():
            raise PolicyError(f"{folder}: the bundle has no policy.onnx")
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        try:
            self._session = ort.InferenceSession(str(onnx_path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # noqa: BLE001  (onnxruntime raises its own classes for a bad file)
            raise PolicyError(f"{onnx_path}: not a loadable ONNX model ({type(exc).__name__})") from None
        outputs = self._session.get_outputs()[0].shape
        if isinstance(outputs[-1], int) and outputs[-1] != self.action_size:
            raise PolicyError(f"{onnx_path}: the network has {outputs[-1]} outputs but the bundle says action_mode "
                              f"{self.action_mode!r} ({self.action_size}); re-export the policy")  # fmt: skip
        inputs = self._session.get_inputs()[0].shape
        if isinstance(inputs[-1], int) and inputs[-1] != self.obs_size:
            raise PolicyError(f"{onnx_path}: the network reads {inputs[-1]} values but the bundle says obs_size "
                              f"{self.obs_size}; re-export the policy")  # fmt: skip
        self._mean = mean
        self._std = None if var is None else np.sqrt(var + epsilon)
        self._clip = clip
        self._low = low.astype(np.float32)
        self._high = high.astype(np.float32)
        #: a residual policy's classical base and how the correction is added (None: the network acts alone)
        self._base: BundlePolicy | None = None
        self._mix: ResidualMix | None = None
        residual = meta.get("residual")
        if residual is not None:
            if not isinstance(residual, dict) or not isinstance(residual.get("scale"), (int, float)):
                raise PolicyError(f"{meta_path}: malformed residual (expected {{scale, base}}); re-export the policy")
            self._base = BundlePolicy.from_meta(residual.get("base"))
            width, depth = self.geometry.plate_extent
            try:
                self._mix = ResidualMix(float(residual["scale"]), (width / 2, depth / 2),
                                        float(residual.get("fade_mm", 0.0)), float(residual.get("inner_mm", 0.0)),
                                        float(residual.get("release_mm", 0.0)), float(residual.get("dwell_s", 0.0)),
                                        1.0 / self.control_hz)  # fmt: skip
            except (TypeError, ValueError, ZeroDivisionError) as exc:
                raise PolicyError(f"{meta_path}: malformed residual ({exc}); re-export the policy") from None

    def reset(self) -> None:
        """Start of an episode (clears the PID's or LQR's state, or a residual policy's base's)."""
        if self.kind in CLASSICAL_KINDS:
            self._classical.reset()
        elif self._base is not None and self._mix is not None:
            self._base.reset()
            self._mix.reset()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Action(s) for observation(s) (…, obs_size), clipped to the action bounds."""
        if self.kind in CLASSICAL_KINDS:
            return self._classical(obs)
        o = np.asarray(obs, dtype=np.float64)
        if self._mean is not None:
            o = bounded((o - self._mean) / self._std, -self._clip, self._clip)
        x = o.astype(np.float32).reshape(-1, o.shape[-1])
        action = self._session.run(None, {"obs": x})[0]
        action = bounded(action, self._low, self._high).reshape(*o.shape[:-1], -1)
        if self._base is not None and self._mix is not None:
            return self._mix(self._base(obs), action, obs)
        return action

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:  # fmt: skip
        """Stable-Baselines3-style ``predict`` (so :func:`~stewart_gym.evaluation.evaluate` runs bundles too)."""
        if episode_start is not None and np.any(episode_start):
            self.reset()
        return self(obs), None
