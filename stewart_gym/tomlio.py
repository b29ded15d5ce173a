"""Reading TOML files with errors that name the file (tomllib, or tomli on Python 3.10)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stewart_gym.errors import ConfigError

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

__all__ = ["read_toml", "tomllib"]


def read_toml(path: str | Path, error: type[Exception] = ConfigError) -> dict[str, Any]:
    """The parsed file; a syntax error or a missing file raises ``error`` naming the file."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not a text file (TOML must be UTF-8 text)") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
