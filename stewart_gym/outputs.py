"""Output paths checked before long work starts: a run that would fail to save its result fails at once; and
the configuration a training run left beside its model (:func:`run_config`); the members an ensemble folder
lists (:func:`ensemble_members`).

Used by the command line, the policy registry and :func:`stewart_gym.training.train`; raises
:class:`~stewart_gym.errors.ConfigError` with what to do.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from stewart_gym.errors import ConfigError, PolicyError
from stewart_gym.inputs import read_json, read_yaml

__all__ = ["ENSEMBLE_FILE", "RUN_GEOMETRY_FILE", "ensemble_members", "make_parent", "model_statistics",
           "no_folders_named", "output_dir", "output_file", "run_config", "stops_held"]

#: The file that makes a folder an ensemble of networks (``stewart-gym ensemble``):
#: ``{"members": ["members/0", ...], "sources": [...], "note": "..."}``.
ENSEMBLE_FILE = "ensemble.json"


def output_file(path: str | Path, *, suffixes: tuple[str, ...] = (), overwrite: bool = True) -> Path:
    """Check that ``path`` can be written, before any long work: its folder exists or can be created, it is
    not a folder, and (with ``overwrite=False``) it does not exist yet. Raises :class:`ConfigError`. The writer
    makes the folder as it writes (:func:`make_parent`)."""
    if not str(path).strip():
        raise ConfigError("an empty output path was given; name the file to write")
    p = Path(path)
    if suffixes and p.suffix.lower() not in suffixes:
        raise ConfigError(f"{p}: expected a file name ending in {' or '.join(suffixes)}")
    _short_names(p)
    if p.is_symlink() and not p.exists():  # written through: its target's folder must be there
        target = _link_target(p)
        if not target.parent.is_dir():
            raise ConfigError(f"{p} is a link to {target}, whose folder does not exist; give another name, or "
                              "remove the link")  # fmt: skip
    if p.is_dir():
        raise ConfigError(f"{p} is a folder; give a file name")
    if p.exists() and not overwrite:
        raise ConfigError(f"{p} exists; give another name or --overwrite")
    _writable_dir(p.parent, p)
    if p.exists() and not os.access(p, os.W_OK):
        raise ConfigError(f"{p}: no permission to write")
    return p


def make_parent(path: str | Path) -> Path:
    """``path`` as a :class:`~pathlib.Path`, its folder made where it is missing (:func:`output_file` checked that
    it can be): what a writer calls just before it writes, so that work done is not lost to a missing folder."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


def output_dir(path: str | Path) -> Path:
    """Check that ``path`` is, or can be created as, a writable folder. Raises :class:`ConfigError`."""
    if not str(path).strip():
        raise ConfigError("an empty output folder was given; name the folder to write into")
    p = Path(path)
    _short_names(p)
    if p.exists() and not p.is_dir():
        raise ConfigError(f"{p} exists and is not a folder")
    _writable_dir(p, p)
    return p


def no_folders_named(folder: Path, names: tuple[str, ...], writer: str, option: str) -> None:
    """Raise :class:`ConfigError` if one of the files ``writer`` (``"the run"``) writes into ``folder`` under
    ``names`` is a folder there (the file would be moved into it, or fail at the end of the work)."""
    blocked = next((folder / name for name in names if (folder / name).is_dir()), None)
    if blocked is not None:
        raise ConfigError(f"{blocked} is a folder, where {writer} writes a file; remove it or give another {option}")


#: Bytes: the longest name of one file or folder most file systems take (ext4, APFS, NTFS: 255).
NAME_MAX = 255


def _short_names(p: Path) -> None:
    long = next((part for part in p.parts if len(os.fsencode(part)) > NAME_MAX), None)
    if long is not None:
        raise ConfigError(f"{p}: the name {long[:40]}… is {len(os.fsencode(long))} bytes long; a file or folder name "
                          f"takes at most {NAME_MAX}")  # fmt: skip


def _link_target(p: Path) -> Path:
    """Where the symbolic link ``p`` leads, followed to its end; :class:`ConfigError` for a loop."""
    try:
        return p.resolve()
    except (RuntimeError, OSError):  # "Symlink loop"
        raise ConfigError(f"{p}: a symbolic link that leads back to itself (a loop); remove it or give another "
                          "name") from None


def _writable_dir(folder: Path, target: Path) -> None:
    """Raise :class:`ConfigError` unless ``target`` (``folder`` or a file in it) can be written: ``folder``, or
    its nearest existing folder, is a folder that takes a new file."""
    existing = folder
    while not existing.exists():
        if existing.is_symlink():  # a link that leads nowhere: nothing can be made through it
            where = "" if existing == target else f"{target}: "
            raise ConfigError(f"{where}{existing} is a link to {_link_target(existing)}, which does not exist; give "
                              "another path, or remove the link")  # fmt: skip
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        raise ConfigError(f"{existing} is a file, not a folder" if existing == folder
                          else f"{folder}: {existing} is a file, not a folder")  # fmt: skip
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ConfigError(f"{folder}: no permission to write in {existing}")
    try:  # a file made there and removed at once: what the permissions do not tell (/proc, a read-only mount, root)
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        raise ConfigError(f"{target}: {existing} takes no new files ({os.strerror(exc.errno or 0).lower()}); "
                          "choose a folder you can write in") from None  # fmt: skip


#: A run trained on a geometry file keeps a copy of the build here, in its folder, and its config.yaml names it
#: (relative to the folder): moving or editing the original leaves the trained policy with its own build.
RUN_GEOMETRY_FILE = "geometry.toml"


def run_config(model_zip: Path) -> dict[str, Any] | None:
    """The ``config.yaml`` of the training run a model belongs to: beside it, or one folder up (``best/``,
    ``checkpoints/``); None where there is none. A geometry file named relative to the run folder (its
    :data:`RUN_GEOMETRY_FILE`) comes back as its full path. Raises :class:`PolicyError` (a ``ValueError``) if it cannot be
    read, ``ImportError`` without pyyaml."""
    for folder in (model_zip.parent, model_zip.parent.parent):
        cfg = folder / "config.yaml"
        if cfg.is_file():
            data = read_yaml(cfg, "run configuration", error=PolicyError)
            if not isinstance(data, dict):
                return None
            env_kwargs = (data.get("hyperparams") or {}).get("env_kwargs") or {}
            geometry = env_kwargs.get("geometry")
            if isinstance(geometry, str) and geometry.endswith(".toml") and not Path(geometry).is_absolute():
                own = folder / geometry  # the run's copy of its build (a run folder moves as a whole)
                if own.is_file():
                    env_kwargs["geometry"] = str(own)
            return data
    return None


def model_statistics(model_zip: Path) -> Path | None:
    """The observation-normalisation statistics (VecNormalize) saved with a model ``.zip``: ``vecnormalize.pkl``
    beside it (a run folder's ``model.zip``, ``best/best_model.zip``), or a checkpoint's own
    ``rl_model_vecnormalize_<n>_steps.pkl`` beside ``rl_model_<n>_steps.zip``; None where there are none."""
    own = model_zip.with_name(model_zip.name.replace("model_", "model_vecnormalize_", 1)).with_suffix(".pkl")
    candidates = [own] if own.name != model_zip.with_suffix(".pkl").name else []
    return next((c for c in (*candidates, model_zip.with_name("vecnormalize.pkl")) if c.is_file()), None)


def ensemble_members(folder: str | Path) -> list[Path]:
    """The member folders an ensemble folder's ``ensemble.json`` lists (relative to it), checked to exist."""
    folder = Path(folder)
    index = folder / ENSEMBLE_FILE
    try:
        listed = read_json(index, "ensemble index", error=PolicyError)["members"]
    except PolicyError:
        raise
    except (ValueError, KeyError, TypeError) as exc:
        raise PolicyError(f"{index}: not a readable ensemble index ({type(exc).__name__}: {exc}); write it with "
                          "stewart-gym ensemble") from None  # fmt: skip
    if not isinstance(listed, list) or not listed or not all(isinstance(m, str) for m in listed):
        raise PolicyError(f"{index}: 'members' must be a non-empty list of folders, got {listed!r}")
    members = [folder / m for m in listed]
    missing = [str(m) for m in members if not (m / "model.zip").is_file()]
    if missing:
        raise PolicyError(f"{index}: no model.zip in member folder(s) {missing}")
    return members


@contextlib.contextmanager
def stops_held() -> Iterator[None]:
    """Hold Ctrl-C, SIGTERM and SIGHUP while a few file operations that belong together run (where signals can be
    blocked, in the main thread: not on Windows); one that came meanwhile acts as soon as they are done."""
    import signal
    import threading

    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    stops = {getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP")}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, stops)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
