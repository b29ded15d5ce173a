"""Reading TOML files with errors that name the file (tomllib, or tomli on Python 3.10), through
:mod:`stewart_gym.inputs`' checks (a regular file of bounded size)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stewart_gym.errors import ConfigError
from stewart_gym.inputs import read_bytes

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

__all__ = ["read_toml", "tomllib"]


def read_toml(path: str | Path, error: type[Exception] = ConfigError, what: str = "TOML file") -> dict[str, Any]:
    """The parsed file (a byte-order mark first, as some editors save, is left out); a missing, oversized or
    non-regular file, or a syntax error, raises ``error`` naming it."""
    data = read_bytes(path, what, error=error)
    try:
        return tomllib.loads(data.decode("utf-8-sig"))
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not a text file (TOML must be UTF-8 text)") from None
