"""One place that turns what a user names as a policy into something that runs.

``--policy`` accepts, everywhere (``evaluate``, ``demo``, ``export``, ``deploy``):

* ``shipped``: the committed policy for the env id (:data:`SHIPPED`);
* ``shipped-camera``: the committed policy trained with the camera sensor model (:data:`SHIPPED_CAMERA`);
* ``shipped-residual``: the committed residual PPO policy, a learned correction on top of a classical
  controller (balance: the LQR → PID's approach; track: the LQR → PID's catching up with the moving target)
  behind the Kalman observer (:data:`SHIPPED_RESIDUAL`);
* ``pid``: the tuned cascaded PID baseline behind the low-pass observer (``policies/pid_gains.json``);
* ``pid-kalman``: the cascaded PID retuned behind the Kalman observer (``policies/pid_kalman_gains.json``);
* ``lqr``: the LQR baseline behind the Kalman observer (``policies/lqr.json``: its design, see
  :func:`~stewart_gym.control.design_lqr`);
* ``lqr-pid``: the LQR bringing the ball in and the PID + Kalman holding it (``policies/lqr_pid.json``, see
  :class:`~stewart_gym.control.HandoverDesign`);
* a **run folder** written by ``stewart-gym train`` (``model.zip`` or
  ``best/best_model.zip``, with ``vecnormalize.pkl`` and ``config.yaml``);
* a **model** ``.zip`` (a run's ``model.zip``, ``best/best_model.zip`` or a
  checkpoint; its run's ``config.yaml`` is found beside it or one folder up);
* an **ensemble** folder written by ``stewart-gym ensemble`` (``ensemble.json``: several networks trained alike,
  acting with the mean of their actions; :func:`write_ensemble`);
* a **bundle** folder written by ``stewart-gym export`` (``bundle.json``);
* a **gains** ``.json`` file: PID gains (as ``tune_pid.py`` writes them), an LQR design (as ``lqr.json``) or
  a hand-over design (as ``lqr_pid.json``, as ``tune_handover.py`` writes it), told apart by their fields;
  each runs behind the observer its ``estimator`` field names (``pid_kalman_gains.json`` says ``kalman``);
  without one the LQR and the hand-over run behind the Kalman observer and PID gains behind the low-pass one;
  ``--estimator`` overrides both.

:func:`resolve_policy` works out which, and what the policy was trained for:
the env id and the env keywords that define its observation and action
(``action_mode``, ``max_tilt``, ``control_hz``). Evaluation builds the env with
those keywords, export writes them into the bundle, and deploy maps actions
with them, so a policy trained in ``"pose"`` or ``"pulse"`` mode stays in that
mode. Nothing here imports torch or Stable-Baselines3 until an SB3 model is
actually loaded, so deploying a bundle needs numpy and onnxruntime only.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stewart_gym.actions import ACTION_SIZES, default_max_tilt
from stewart_gym.control import CLASSICAL, CLASSICAL_KINDS, design_estimator, design_kind
from stewart_gym.errors import ConfigError, PolicyError
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.inputs import read_json
from stewart_gym.outputs import (
    ENSEMBLE_FILE,
    RUN_GEOMETRY_FILE,
    ensemble_members,
    model_statistics,
    run_config,
    stops_held,
)

__all__ = ["POLICY_DIR", "SHIPPED", "SHIPPED_CAMERA", "SHIPPED_RESIDUAL", "PolicySource", "deployable_policy",
           "export_policy", "learned_models_importable", "load_for_evaluation", "load_policy", "resolve_policy",
           "write_ensemble"]  # fmt: skip

POLICY_DIR = Path(__file__).resolve().parent / "policies"
#: Folder under ``policies/`` of the shipped policy of each env id.
SHIPPED = {("StewartBallBalance-v0", "servo-hexapod"): "balance", ("StewartBallTrack-v0", "servo-hexapod"): "track",
           ("StewartBallBalance-v0", "memememe-liverpool"): "balance_memememe",
           ("StewartBallBalance-v0", "desk-rect"): "balance_desk_rect",
           # the balance policy, trained without pushes, handles them: see the docs' Environments page
           ("StewartBallDisturbance-v0", "servo-hexapod"): "balance"}
#: The shipped policies trained with the camera sensor model (``--policy shipped-camera``): folder under ``policies/``.
SHIPPED_CAMERA = {("StewartBallBalance-v0", "servo-hexapod"): "balance_camera"}
#: The shipped residual policies (``--policy shipped-residual``: PPO corrections of a classical controller, the base
#: their config.yaml names): folder under ``policies/``.
SHIPPED_RESIDUAL = {("StewartBallBalance-v0", "servo-hexapod"): "balance_residual",
                    ("StewartBallTrack-v0", "servo-hexapod"): "track_residual",
                    # as SHIPPED's: the balance residual, trained without pushes (docs: Environments)
                    ("StewartBallDisturbance-v0", "servo-hexapod"): "balance_residual"}
#: What ``stewart-gym train`` needs, beyond ``--env`` and ``--geometry``, to train the like of each shipped kind.
TRAIN_OPTIONS = {"shipped": "", "shipped-camera": " --sensor camera", "shipped-residual": " --hyperparams ppo_residual"}
SHIPPED_TABLES = {"shipped": SHIPPED, "shipped-camera": SHIPPED_CAMERA, "shipped-residual": SHIPPED_RESIDUAL}
DEFAULT_ENV = "StewartBallBalance-v0"
#: Env keywords that change what a policy sees or what its action means: a policy keeps them wherever it runs.
POLICY_ENV_KEYS = ("action_mode", "max_tilt", "control_hz", "geometry", "estimator", "integral")
DEFAULT_GEOMETRY = "servo-hexapod"
#: Env keywords of the track task that deploy uses for its moving target.
TASK_ENV_KEYS = ("trajectory",)
#: Env keywords of the world a policy was trained in, not of the policy: ``evaluate`` runs it there unless told
#: otherwise (``--backend``, ``--sensor``), and any policy can be evaluated in another.
WORLD_ENV_KEYS = ("backend", "sensor")
_KINDS_TEXT = ("'shipped', 'shipped-camera', 'shipped-residual', 'pid', 'pid-kalman', 'lqr', 'lqr-pid', a run folder, "
               "a model .zip, an ensemble folder, a bundle folder or a gains .json (PID gains, an LQR or hand-over design)")


@dataclass(frozen=True)
class PolicySource:
    """A resolved ``--policy`` value.

    Attributes:
        spec: What the user gave.
        kind: ``"pid"`` (gains file), ``"lqr"`` (LQR design file), ``"handover"`` (LQR → PID design file),
            ``"sb3"`` (a Stable-Baselines3 model), ``"ensemble"`` (several, averaged) or ``"bundle"``
            (ONNX/PID/LQR/hand-over bundle).
        path: The gains file, the model ``.zip``, the ensemble folder or the bundle folder.
        env_id: The env id the policy was trained (or exported) for.
        env_kwargs: The env keywords that define its observation and action (and the track's trajectory).
        bundle: A ready-made bundle of this policy, if there is one (the shipped policies have one).
    """

    spec: str
    kind: str
    path: Path
    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    bundle: Path | None = None

    def __post_init__(self) -> None:
        from stewart_gym.envs import ENV_IDS

        if self.env_id not in ENV_IDS:
            raise PolicyError(f"policy {self.spec!r} was made for env {self.env_id!r}, which stewart_gym does not have "
                              f"({', '.join(ENV_IDS)}); its bundle.json or config.yaml names the env")  # fmt: skip
        if not isinstance(self.env_kwargs, dict):
            raise PolicyError(f"policy {self.spec!r}: its env_kwargs must be a mapping of env keywords, got "
                              f"{self.env_kwargs!r}")  # fmt: skip

    @property
    def action_mode(self) -> str:
        return str(self.env_kwargs.get("action_mode", "tilt"))

    @property
    def geometry(self) -> Any:
        """The geometry the policy was trained for: a preset name or TOML path, or (a bundle for a build of its own)
        the :class:`~stewart_gym.geometry.PlatformGeometry` the bundle holds."""
        geometry = self.env_kwargs.get("geometry", DEFAULT_GEOMETRY)
        return geometry if isinstance(geometry, PlatformGeometry) else str(geometry)

    @property
    def geometry_label(self) -> str:
        """The geometry as a message names it: a preset name or path as given, or a held geometry's name."""
        geometry = self.geometry
        return geometry.name if isinstance(geometry, PlatformGeometry) else geometry

    @property
    def label(self) -> str:
        """What to call it in a table or a plot: a name as given, a path as typed (a run folder, not its model)."""
        return self.spec.rstrip("/") or self.spec

    @property
    def estimator(self) -> str:
        """How the observer estimates the ball's state for this policy (``lowpass`` or ``kalman``)."""
        return str(self.env_kwargs.get("estimator", "lowpass"))


def resolve_policy(spec: str, env_id: str | None = None, geometry: str | None = None,
                   estimator: str | None = None) -> PolicySource:  # fmt: skip
    """What ``spec`` names (see the module docstring); raises :class:`PolicyError` with what to do instead.

    ``env_id`` and ``geometry`` pick the shipped policy (default
    ``StewartBallBalance-v0`` on ``servo-hexapod``) and are recorded for the
    PID and LQR; a trained model or bundle keeps the env id and geometry it was trained for.
    ``estimator`` replaces the observer the policy runs behind (by default its own: what it was trained or
    exported with; ``kalman`` for the LQR, ``lowpass`` for the PID).
    """
    source = _resolve(spec, env_id, geometry)
    if estimator is None:
        return source
    return PolicySource(source.spec, source.kind, source.path, source.env_id,
                        {**source.env_kwargs, "estimator": estimator}, source.bundle)  # fmt: skip


def _resolve(spec: str, env_id: str | None, geometry: str | None) -> PolicySource:
    if spec in CLASSICAL:
        kind, name, estimator = CLASSICAL[spec]
        kwargs = {"action_mode": "tilt", "geometry": geometry or DEFAULT_GEOMETRY, "estimator": estimator}
        return PolicySource(spec, kind, POLICY_DIR / name, env_id or DEFAULT_ENV, kwargs)
    if spec in SHIPPED_TABLES:
        env_id, geo = env_id or DEFAULT_ENV, geometry or DEFAULT_GEOMETRY
        table = SHIPPED_TABLES[spec]
        if (env_id, geo) not in table:
            have = ", ".join(f"{e} on {g}" for e, g in table)
            raise PolicyError(f"no {spec} policy for {env_id} on {geo}; {spec} policies: {have}; train one for it: "
                              f"stewart-gym train --env {env_id} --geometry {geo}{TRAIN_OPTIONS[spec]}")  # fmt: skip
        folder = POLICY_DIR / table[(env_id, geo)]
        extra = {"geometry": geo, **({"sensor": "camera"} if spec == "shipped-camera" else {})}
        ensemble = (folder / ENSEMBLE_FILE).is_file()
        kind, model = ("ensemble", folder) if ensemble else ("sb3", folder / "model.zip")
        if (folder / "bundle" / "bundle.json").is_file():  # its settings from JSON: no YAML needed to deploy it
            env_kwargs = {**_bundle_source(spec, folder / "bundle").env_kwargs, **extra}
            return PolicySource(spec, kind, model, env_id, env_kwargs, folder / "bundle")
        source = _ensemble_source(spec, folder) if ensemble else _sb3_source(spec, model)
        return PolicySource(spec, kind, source.path, env_id, {**source.env_kwargs, **extra})
    path = Path(spec)
    if not path.exists():
        raise PolicyError(f"policy {spec!r}: no such file or folder; give {_KINDS_TEXT}")
    if path.is_dir():
        if (path / "bundle.json").exists():
            return _bundle_source(spec, path)
        if (path / ENSEMBLE_FILE).exists():
            return _ensemble_source(spec, path)
        for name in ("model.zip", "best/best_model.zip", "best_model.zip"):
            if (path / name).is_file():
                return _sb3_source(spec, path / name)
        raise PolicyError(f"policy {spec!r}: the folder has no bundle.json, model.zip or best/best_model.zip; "
                          f"give {_KINDS_TEXT}")  # fmt: skip
    if path.suffix == ".zip":
        return _sb3_source(spec, path)
    if path.name == "bundle.json":  # a bundle's description, named instead of its folder: the bundle
        return _bundle_source(spec, path.parent)
    if path.suffix == ".json":
        # a readable JSON file, checked here; its kind from its fields; the gains themselves when loaded
        values = _read_json(path)
        try:  # the observer the file names; else the LQR's and the hand-over's model is the Kalman observer's
            named = design_estimator(values)
        except ValueError as exc:
            raise PolicyError(f"{path}: {exc}") from None
        kind = design_kind(values)
        kwargs = {"action_mode": "tilt", "geometry": geometry or DEFAULT_GEOMETRY}
        if named is not None or kind != "pid":
            kwargs["estimator"] = named or "kalman"
        return PolicySource(spec, kind, path, env_id or DEFAULT_ENV, kwargs)
    raise PolicyError(f"policy {spec!r}: not a .zip model or a .json gains or design file; give {_KINDS_TEXT}")


def _read_json(path: Path) -> dict[str, Any]:
    data = read_json(path, "JSON file", error=PolicyError)
    if not isinstance(data, dict):
        raise PolicyError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


def _run_config(model_zip: Path) -> dict[str, Any] | None:
    """The ``config.yaml`` of the run a model belongs to (:func:`~stewart_gym.outputs.run_config`)."""
    try:
        return run_config(model_zip)
    except ImportError:
        raise PolicyError("reading a training run needs pyyaml: pip install 'stewart_gym[train]'") from None
    except ValueError as exc:
        raise PolicyError(str(exc)) from None


def _sb3_source(spec: str, model_zip: Path) -> PolicySource:
    if not model_zip.is_file():
        raise PolicyError(f"policy {spec!r}: no model at {model_zip}")
    cfg = _run_config(model_zip)
    if cfg is None and (model_zip.with_suffix("") / "config.yml").is_file():  # RL Zoo's layout: <env id>.zip
        raise PolicyError(f"policy {spec!r}: {model_zip} is an RL Zoo model (its statistics and settings are in "
                          f"{model_zip.with_suffix('')}/, which stewart-gym does not read): evaluate it with "
                          "python -m rl_zoo3.enjoy, or train with stewart-gym train for evaluate, export and "
                          "deploy")  # fmt: skip
    if cfg is None:
        return PolicySource(spec, "sb3", model_zip, DEFAULT_ENV, {})  # action mode inferred when loaded
    options, hp = cfg.get("options") or {}, cfg.get("hyperparams") or {}
    if hp.get("normalize") and model_statistics(model_zip) is None:  # it would see raw observations: nonsense
        raise PolicyError(f"policy {spec!r}: {model_zip} was trained on normalised observations, and their "
                          "statistics are not beside it (vecnormalize.pkl, or a checkpoint's "
                          "rl_model_vecnormalize_<steps>_steps.pkl); keep the run folder together")  # fmt: skip
    env_kwargs = hp.get("env_kwargs") or {}
    if not isinstance(env_kwargs, dict):
        raise PolicyError(f"policy {spec!r}: its config.yaml's hyperparams.env_kwargs must be a mapping of env "
                          f"keywords, got {env_kwargs!r}")  # fmt: skip
    kept = {k: env_kwargs[k] for k in POLICY_ENV_KEYS + TASK_ENV_KEYS if k in env_kwargs}
    kept.update({k: env_kwargs[k] for k in WORLD_ENV_KEYS if env_kwargs.get(k) is not None})
    kept.setdefault("action_mode", "tilt")
    if hp.get("residual"):  # not an env keyword: what the learned correction is added to (see sb3_models)
        kept["residual"] = hp["residual"]
    return PolicySource(spec, "sb3", model_zip, str(options.get("env_id", DEFAULT_ENV)), kept)


def _ensemble_source(spec: str, folder: Path) -> PolicySource:
    """An ensemble folder: its members' env id and keywords, which must agree (they are one recipe's networks)."""
    members = [_sb3_source(spec, m / "model.zip") for m in ensemble_members(folder)]
    for member in members[1:]:
        _check_alike(members[0], member)
    return PolicySource(spec, "ensemble", folder, members[0].env_id, members[0].env_kwargs)


def _check_alike(first: PolicySource, other: PolicySource) -> None:
    """Raise :class:`PolicyError` unless two networks were trained for the same env id, observation and action
    (and residual base): only then can their actions be averaged."""
    if first.env_id != other.env_id:
        raise PolicyError(f"{other.path} was trained for {other.env_id} but {first.path} for {first.env_id}; an "
                          "ensemble's networks must be trained alike (one recipe, different seeds)")  # fmt: skip
    if first.env_kwargs != other.env_kwargs:
        differ = sorted(k for k in {*first.env_kwargs, *other.env_kwargs}
                        if first.env_kwargs.get(k) != other.env_kwargs.get(k))  # fmt: skip
        raise PolicyError(f"{other.path} and {first.path} were trained with different {', '.join(differ)}; an "
                          "ensemble's networks must be trained alike (one recipe, different seeds)")  # fmt: skip


def write_ensemble(runs: list[str], out_dir: str | Path, note: str = "") -> Path:
    """Write the ensemble folder of ``runs`` (run folders or model ``.zip`` files of one recipe, trained with
    different seeds) into ``out_dir``, which must not hold one yet: ``members/<k>/`` with each run's model,
    normalisation statistics, ``config.yaml`` and ``metrics.json``, and ``ensemble.json`` listing them. The
    runs are checked before anything is written (trained models that load, each with its statistics, for the
    same env id, observation, action and residual base). Raises :class:`PolicyError` naming what is wrong."""
    import shutil

    from stewart_gym.sb3_models import EnsemblePolicy, load_sb3

    if len(runs) < 2:
        raise PolicyError(f"an ensemble averages 2 or more trained networks; got {len(runs)}")
    sources = [resolve_policy(r) for r in runs]
    seen: dict[str, str] = {}
    for source in sources:
        if source.kind != "sb3":
            raise PolicyError(f"{source.spec!r} is not a trained network (a run folder or a model .zip), so it "
                              "cannot be an ensemble's member")  # fmt: skip
        stats = model_statistics(source.path)  # the network and its statistics (a copied run folder is the same)
        digest = hashlib.sha256(source.path.read_bytes() + (stats.read_bytes() if stats else b"")).hexdigest()
        if digest in seen:
            raise PolicyError(f"{source.spec!r} and {seen[digest]!r} are the same network; an ensemble averages "
                              "different ones (the same recipe, other seeds)")  # fmt: skip
        seen[digest] = source.spec
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise PolicyError(f"{out} already exists and is not an empty folder; give a new --out")
    models = [load_sb3(s.path) for s in sources]  # each loads, with its statistics (a file that is no model says so)
    for source in sources[1:]:
        _check_alike(sources[0], source)
    EnsemblePolicy(models)  # the same sizes: before anything is written
    members = []
    for k, source in enumerate(sources):
        member = out / "members" / str(k)
        member.mkdir(parents=True)
        shutil.copyfile(source.path, member / "model.zip")
        stats = model_statistics(source.path)
        if stats is not None:
            shutil.copyfile(stats, member / "vecnormalize.pkl")
        for name in ("config.yaml", "metrics.json", RUN_GEOMETRY_FILE):  # beside the model, or one folder up
            found = next((f / name for f in (source.path.parent, source.path.parent.parent) if (f / name).is_file()),
                         None)  # fmt: skip
            if found is not None:
                shutil.copyfile(found, member / name)
        members.append(f"members/{k}")
    index = {"members": members, "sources": [str(r) for r in runs], "note": note}
    (out / ENSEMBLE_FILE).write_text(json.dumps(index, indent=2) + "\n", encoding="utf-8")
    _ensemble_source(str(out), out)  # the copies read back alike
    return out


def _bundle_source(spec: str, folder: Path) -> PolicySource:
    """A bundle folder's policy, its fields checked against each other: the observer, action mode and integral its
    env keywords name are the bundle's own, and its geometry is the one it holds (a preset's name where it is a
    preset, else the held geometry itself). What evaluate alone needs is checked there
    (:func:`check_bundle_env`): deploy runs without gymnasium."""
    from stewart_gym.hardware.export import bundle_geometry
    from stewart_gym.presets import PRESETS, load_preset

    meta_path = folder / "bundle.json"
    meta = _read_json(meta_path)
    if not isinstance(meta.get("env_kwargs") or {}, dict):
        raise PolicyError(f"{meta_path}: env_kwargs must be a mapping of env keywords, got "
                          f"{meta['env_kwargs']!r}; export the policy again")  # fmt: skip
    env_kwargs = dict(meta.get("env_kwargs") or {})
    env_id = meta.get("env_id", DEFAULT_ENV)
    for key in ("action_mode", "estimator", "integral", "control_hz", "max_tilt"):
        if env_kwargs.get(key) is not None and key in meta and env_kwargs[key] != meta[key]:
            raise PolicyError(f"{meta_path}: env_kwargs.{key} {env_kwargs[key]!r} is not the bundle's {key} "
                              f"{meta[key]!r}; export the policy again")  # fmt: skip
    env_kwargs["action_mode"] = meta.get("action_mode", "tilt")
    if "geometry" in meta:
        geometry = bundle_geometry(meta, meta_path)
        preset = geometry.name in PRESETS and load_preset(geometry.name) == geometry
        env_kwargs["geometry"] = geometry.name if preset else geometry
    if "estimator" in meta:
        env_kwargs["estimator"] = str(meta["estimator"])
    if meta.get("integral") is True:
        env_kwargs["integral"] = True
    return PolicySource(spec, "bundle", folder, str(env_id), env_kwargs, folder)


# ---------------------------------------------------------------- loading
def load_policy(spec: str | PolicySource, env_id: str | None = None) -> Any:
    """A policy object with SB3's ``predict`` for evaluation: an SB3 model, the PID or a bundle."""
    source = spec if isinstance(spec, PolicySource) else resolve_policy(spec, env_id)
    if source.kind in CLASSICAL_KINDS:
        return load_classical(source.kind, source.path, source.geometry)
    if source.kind == "bundle":
        from stewart_gym.hardware.export import BundlePolicy

        return BundlePolicy(source.path)
    if source.bundle is not None and not learned_models_importable():
        from stewart_gym.hardware.export import BundlePolicy

        _note_once("note: torch is not installed here: the shipped learned policies run as their ONNX bundles (the "
                   "same networks; pip install 'stewart_gym[train]' to train and to run trained models)")  # fmt: skip
        return BundlePolicy(source.bundle)
    from stewart_gym.sb3_models import ResidualPolicy, check_residual, load_learned, residual_base, residual_mix

    policy = load_learned(source.path)
    if source.env_kwargs.get("residual"):
        spec = check_residual(source.env_kwargs["residual"], recorded=True)
        from stewart_gym.presets import load_geometry

        width, depth = load_geometry(source.geometry).plate_extent
        half = (width / 2, depth / 2)
        dt = 1.0 / float(source.env_kwargs.get("control_hz", 50))  # the period it was trained at, as training ran it
        policy = ResidualPolicy(policy, residual_base(spec, source.geometry, half, dt), residual_mix(spec, half, dt))
    if "action_mode" in source.env_kwargs and policy.action_size != ACTION_SIZES[source.action_mode]:
        raise PolicyError(f"{source.path}: the model has {policy.action_size} actions but its run configuration says "
                          f"action_mode {source.action_mode!r} ({ACTION_SIZES[source.action_mode]})")  # fmt: skip
    return policy


def learned_models_importable() -> bool:
    """Whether Stable-Baselines3 and torch are installed (the ``train`` extra): without them, a shipped learned
    policy runs as its ONNX bundle (onnxruntime), and other trained models cannot run."""
    try:
        import stable_baselines3  # noqa: F401  (imports torch)
    except ImportError:
        return False
    return True


_NOTES_SAID: set[str] = set()


def _note_once(text: str) -> None:
    """``text`` on stderr, the first time in this process (through the package's logger, as its other notes)."""
    import logging

    if text not in _NOTES_SAID:
        _NOTES_SAID.add(text)
        logging.getLogger("stewart_gym").warning(text)


def load_for_evaluation(spec: str, env_id: str | None = None, geometry: str | None = None,
                        estimator: str | None = None) -> tuple[PolicySource, Any, dict[str, Any]]:  # fmt: skip
    """(source, policy, env keywords): what ``evaluate`` and ``demo`` need to run ``spec`` as it was trained.

    A trained policy runs on the geometry it was trained for; asking for another
    one raises :class:`PolicyError` naming both (the PID runs on any).
    """
    source = resolve_policy(spec, env_id, geometry, estimator)
    if source.kind == "bundle":
        check_bundle_env(source)
    if geometry is not None and source.kind not in CLASSICAL_KINDS and not same_geometry(geometry, source.geometry):
        raise PolicyError(f"policy {spec!r} was trained for geometry {source.geometry_label!r}, not {geometry!r}: "
                          f"train one for {geometry!r} (stewart-gym train --geometry {geometry}), or evaluate the "
                          "pid")  # fmt: skip
    policy = load_policy(source)
    return source, policy, resolved_env_kwargs(source, getattr(policy, "action_size", None))


def check_bundle_env(source: PolicySource) -> None:
    """A bundle's env keywords, as evaluate builds its env from them: keywords its env takes, and the engine and
    sensor it names among the known ones. Raises :class:`PolicyError` naming the bundle's file."""
    from stewart_gym.envs import ENV_IDS
    from stewart_gym.envs.ball_env import SENSOR_NAMES, env_keywords
    from stewart_gym.sim.engines import BACKEND_NAMES

    meta_path, env_kwargs = source.path / "bundle.json", source.env_kwargs
    unknown = sorted(set(env_kwargs) - env_keywords(ENV_IDS[source.env_id][0]) - {"residual"})
    if unknown:
        raise PolicyError(f"{meta_path}: env_kwargs: {source.env_id} takes no keyword(s) {unknown}; export the policy "
                          "again")  # fmt: skip
    for key, names in (("backend", (*BACKEND_NAMES, "auto")), ("sensor", SENSOR_NAMES)):
        if key in env_kwargs and env_kwargs[key] not in names:
            raise PolicyError(f"{meta_path}: env_kwargs.{key} must be one of {list(names)}, got {env_kwargs[key]!r}; "
                              "export the policy again")  # fmt: skip


def same_geometry(a: str | Any, b: str | Any) -> bool:
    """Whether two geometry specs (preset names, TOML paths or geometries) describe the same platform."""
    from stewart_gym.presets import load_geometry

    return a == b or load_geometry(a) == load_geometry(b)


def load_classical(kind: str, path: Path, geometry: str | Any = DEFAULT_GEOMETRY) -> Any:
    """The classical controller of ``kind`` (``pid``, ``lqr`` or ``handover``) whose gains or design are in
    ``path``, for ``geometry`` (:func:`~stewart_gym.control.classical_controller`: the PID's gains adapted,
    the LQR designed); its observation scales follow the plate."""
    from stewart_gym.control import classical_controller
    from stewart_gym.presets import load_geometry

    design = read_design(path, kind)
    geometry = load_geometry(geometry)  # a bad geometry is the geometry's error, not the gains file's
    try:  # what only the build can tell (a dither against its max tilt)
        controller = classical_controller(kind, design, geometry)
    except ValueError as exc:
        raise PolicyError(f"{path}: {exc}") from None
    given = getattr(getattr(design, "pid", design), "max_tilt", None)
    used = default_max_tilt(geometry)  # what gains_for_geometry gives the PID
    if given is not None and not math.isclose(given, used, rel_tol=1e-9):
        _note_once(f"note: {path}: max_tilt {given:.6g} rad is not used: the controller's tilt at action ±1 is the "
                   f"env's, {used:.6g} rad on {geometry.name!r} (a PID's max_tilt must match the env's)")  # fmt: skip
    return controller


def read_design(path: Path, kind: str) -> Any:
    """The PID's gains (``kind`` "pid"), the LQR's design ("lqr") or the hand-over's ("handover") in the JSON
    file ``path``, checked
    (:func:`~stewart_gym.control.checked_design`): finite numbers, and no negative size."""
    from stewart_gym.control import checked_design

    try:
        return checked_design(_read_json(path), kind)
    except ValueError as exc:
        raise PolicyError(f"{path}: {exc}") from None


def resolved_env_kwargs(source: PolicySource, model_action_size: int | None = None) -> dict[str, Any]:
    """The env keywords to evaluate ``source`` with (only those that define its observation and action)."""
    kwargs = {k: v for k, v in source.env_kwargs.items() if k in POLICY_ENV_KEYS}
    if "action_mode" not in source.env_kwargs and model_action_size is not None:
        if model_action_size == 2:
            kwargs["action_mode"] = "tilt"
        else:
            raise PolicyError(f"{source.path}: a model with {model_action_size} actions but no config.yaml beside it "
                              "(or one folder up): cannot tell 'pose' from 'pulse' mode; keep the run folder together")
    return kwargs


# ------------------------------------------------------------- deployment
def deployable_policy(source: PolicySource) -> Any:
    """A :class:`~stewart_gym.hardware.export.BundlePolicy` (numpy + onnxruntime only) for ``deploy``."""
    from stewart_gym.hardware.export import BundlePolicy

    if source.kind in CLASSICAL_KINDS:
        return BundlePolicy.from_meta(_classical_meta(source))
    if source.bundle is not None:
        policy = BundlePolicy(source.bundle)
        policy.estimator = source.estimator  # the bundle's own, unless --estimator replaced it
        return policy
    raise PolicyError(f"policy {source.spec!r} is a trained network (Stable-Baselines3); deploy runs bundles: "
                      f"export it first (stewart-gym export --policy {source.spec} --out BUNDLE_DIR) and deploy "
                      "BUNDLE_DIR")  # fmt: skip


def _classical_meta(source: PolicySource) -> dict[str, Any]:
    """The ``bundle.json`` content of the classical controller named by ``source``, for its geometry and
    observer."""
    from dataclasses import asdict

    from stewart_gym.hardware.export import classical_meta

    controller = load_policy(source)
    return classical_meta(source.kind, asdict(controller.gains), source.env_id, source.geometry, source.estimator)


#: The files of a bundle folder: ``export`` writes over these, and refuses a folder that holds anything else.
BUNDLE_FILES = ("bundle.json", "policy.onnx", "policy.onnx.data")


def export_policy(source: PolicySource, out_dir: str | Path, overwrite: bool = False) -> Path:
    """Write ``source`` as a bundle folder (ONNX + JSON, or the PID's gains) and return the folder. A folder that
    holds a bundle already is refused unless ``overwrite``; the new bundle is written beside it first and takes
    its place only once whole (a file of the old one that the new one lacks is removed), so that a refusal or a
    failure leaves the old bundle as it was, and no new folder."""
    import shutil

    out = Path(out_dir)
    other = sorted(p.name for p in out.iterdir() if p.name not in BUNDLE_FILES and not p.name.startswith(STAGING)
                   ) if out.is_dir() else []  # fmt: skip
    if other:  # a run folder, say: a bundle.json there would take the place of its model
        raise ConfigError(f"--out {out} holds other files ({', '.join(other[:3])}{', …' if len(other) > 3 else ''}); "
                          "export into a new or empty folder, or over an earlier bundle (--overwrite)")  # fmt: skip
    held = [name for name in BUNDLE_FILES if (out / name).exists()]
    if held and not overwrite:
        raise ConfigError(f"--out {out} holds a bundle already ({held[0]}); give --overwrite to replace it, or "
                          "export into another folder")  # fmt: skip
    new = [p for p in (out, *out.parents) if not p.exists()]  # the folders this export makes
    work: Path | None = None
    try:
        out.mkdir(parents=True, exist_ok=True)
        work = _staging(out)
        _write_bundle(source, work)
        with stops_held():  # the whole new bundle takes the old one's place, not a part of it
            for name in BUNDLE_FILES:
                if (work / name).exists():
                    os.replace(work / name, out / name)
                else:
                    (out / name).unlink(missing_ok=True)
    except BaseException:
        if work is not None:
            shutil.rmtree(work, ignore_errors=True)
        if new:  # a refusal or a failure leaves no folder behind
            shutil.rmtree(new[-1], ignore_errors=True)
        raise
    for left in (work, *out.glob(f"{STAGING}*")):  # (and what an export killed before left in the folder)
        shutil.rmtree(left, ignore_errors=True)
    return out


#: How the folder an export makes its bundle in begins (beside the bundle's folder, or in it).
STAGING = ".export-"


def _staging(out: Path) -> Path:
    """A new folder to make ``out``'s bundle in: beside ``out``, or in it where its parent cannot be written
    (``--out .`` in a home folder)."""
    import tempfile

    try:
        return Path(tempfile.mkdtemp(prefix=f"{STAGING}{out.resolve().name}-", dir=out.resolve().parent))
    except OSError:
        return Path(tempfile.mkdtemp(prefix=STAGING, dir=out))


def _write_bundle(source: PolicySource, out: Path) -> None:
    """Write ``source``'s bundle files into the folder ``out``."""
    from stewart_gym.hardware.export import export_bundle_copy, export_sb3

    if source.kind in CLASSICAL_KINDS:
        (out / "bundle.json").write_text(json.dumps(_classical_meta(source), indent=2) + "\n", encoding="utf-8")
        return
    if source.kind == "bundle":
        export_bundle_copy(source.path, out)
        meta = _read_json(out / "bundle.json")
        if meta.get("estimator", "lowpass") != source.estimator:  # --estimator asked for another observer
            text = json.dumps({**meta, "estimator": source.estimator}, indent=2) + "\n"
            (out / "bundle.json").write_text(text, encoding="utf-8")
        return
    policy = load_policy(source)  # the model loads and its action size matches its configuration
    env_kwargs = {**source.env_kwargs, **resolved_env_kwargs(source, policy.action_size)}
    export_sb3(source.path, out, source.env_id, env_kwargs)
