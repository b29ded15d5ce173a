"""Input files, checked before they are read: a regular file (not a folder, a device or a pipe) of bounded size,
decoded as UTF-8 text; YAML without repeated keys.

Every file a command reads goes through :func:`read_text` or :func:`read_bytes`, so ``--geometry /dev/zero``, a
folder or a 10 GB file is one error naming the path, before any work. Errors are of the class the caller names
(:class:`~stewart_gym.errors.ConfigError` by default), so a calibration stays a calibration error.
"""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path
from typing import Any

from stewart_gym.errors import ConfigError

__all__ = ["CONFIG_LIMIT", "DATA_LIMIT", "input_file", "read_bytes", "read_json", "read_text", "read_yaml"]

#: bytes: the largest configuration file (TOML, YAML, JSON) read.
CONFIG_LIMIT = 4 * 2**20
#: bytes: the largest data file (a CSV of poses, an image) read.
DATA_LIMIT = 64 * 2**20


def _size(n: int) -> str:
    return f"{n / 2**20:.0f} MiB" if n >= 2**20 else f"{n} bytes"


def input_file(path: str | os.PathLike, what: str = "file", limit: int = CONFIG_LIMIT,
               error: type[Exception] = ConfigError) -> Path:  # fmt: skip
    """``path`` checked as an input: it exists, is a regular file and holds at most ``limit`` bytes."""
    p = Path(path)
    if not str(path):
        raise error(f"an empty path was given for the {what}")
    try:
        st = p.stat()
    except FileNotFoundError:
        raise error(f"{p}: no such {what} (check the path)") from None
    except OSError as exc:
        raise error(f"{p}: cannot read the {what} ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{p} is a folder; give the {what} itself")
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{p} is not a regular file (a device, a pipe or a socket); give the {what} as a file")
    if st.st_size > limit:
        raise error(f"{p}: {_size(st.st_size)}, more than a {what} can be ({_size(limit)})")
    return p


def read_bytes(path: str | os.PathLike, what: str = "file", limit: int = CONFIG_LIMIT,
               error: type[Exception] = ConfigError) -> bytes:  # fmt: skip
    """The bytes of an :func:`input_file` (never more than ``limit``, even if the file grows meanwhile)."""
    p = input_file(path, what, limit, error)
    try:
        with p.open("rb") as fh:
            data = fh.read(limit + 1)
    except OSError as exc:
        raise error(f"{p}: cannot read the {what} ({exc.strerror or exc})") from None
    if len(data) > limit:
        raise error(f"{p}: more than a {what} can be ({_size(limit)})")
    return data


def read_text(path: str | os.PathLike, what: str = "file", limit: int = CONFIG_LIMIT,
              error: type[Exception] = ConfigError) -> str:  # fmt: skip
    """The text of an :func:`input_file`, without the byte-order mark some editors put first (Notepad's "UTF-8
    with BOM"); a file that is not UTF-8 text raises ``error``."""
    data = read_bytes(path, what, limit, error)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise error(f"{path}: not a text file (a {what} must be UTF-8 text)") from None


def read_yaml(path: str | os.PathLike, what: str = "YAML file", error: type[Exception] = ConfigError) -> Any:
    """The parsed YAML of an :func:`input_file`; invalid YAML or a key given twice in one mapping raises ``error``
    naming the file, the key and the line."""
    import yaml

    text = read_text(path, what, CONFIG_LIMIT, error)

    class UniqueKeyLoader(yaml.SafeLoader):
        """The safe loader, refusing a key given twice in one mapping (PyYAML keeps the last silently)."""

    def mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # `<<: *anchor`: its keys may be overridden here
                continue
            key = loader.construct_object(key_node, deep=deep)
            try:
                if key in seen:
                    raise error(f"{path}, line {key_node.start_mark.line + 1}: {key!r} is given twice; keep one")
                seen.add(key)
            except TypeError:  # an unhashable key: the constructor below says so
                pass
        return loader.construct_mapping(node, deep=deep)

    UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    try:
        return yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506  (a SafeLoader subclass)
    except RecursionError:  # brackets nested thousands deep
        raise error(f"{path}: nested too deeply to read (a damaged or generated file?)") from None
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None


def read_json(path: str | os.PathLike, what: str = "JSON file", error: type[Exception] = ConfigError) -> Any:
    """The parsed JSON of an :func:`input_file`; invalid JSON, a key given twice in one object (Python's parser
    keeps the last silently), or a number too long to read raises ``error`` naming the file."""
    import json

    text = read_text(path, what, CONFIG_LIMIT, error)

    class GivenTwice(Exception):
        """A key given twice in one object."""

    def unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key, value in pairs:
            if key in out:
                raise GivenTwice(key)
            out[key] = value
        return out

    try:
        return json.loads(text, object_pairs_hook=unique)
    except GivenTwice as exc:
        raise error(f"{path}: {exc.args[0]!r} is given twice in one object; keep one") from None
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:  # brackets nested thousands deep
        raise error(f"{path}: nested too deeply to read (a damaged or generated file?)") from None
    except ValueError:  # a whole number of thousands of digits: "Exceeds the limit … for integer string …"
        raise error(f"{path}: a number too long to read ({sys.get_int_max_str_digits()} digits at most)") from None
