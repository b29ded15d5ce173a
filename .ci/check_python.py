"""Can this Python set stewart_gym up? `make` runs it with the Python it will build .venv from, before anything
is installed: ``python3 .ci/check_python.py``.

It exits 0 when it can. Otherwise it prints one line, ``error: …`` (what is missing, what to do), and exits 1,
instead of a long pip failure later: for a Python older than 3.10, and where pip has to compile PyBullet from
its source (PyBullet 3.2.7 publishes wheels for Linux on x86-64 with Python 3.10 and 3.11 only) without the
Python headers or a C++ compiler. ``--demo`` checks for ``make demo``'s install (the ``demo`` extra), which
takes PyBullet on Python 3.10 and 3.11 only and MuJoCo (wheels for every current Python) on newer ones; the
``dev`` extra of ``make test`` takes PyBullet on every Python.
"""

from __future__ import annotations

import os
import platform
import shutil
import sys
import sysconfig

#: The newest Python that PyBullet 3.2.7 publishes a wheel for (Linux, x86-64).
NEWEST_PYBULLET_WHEEL = (3, 11)


def problem(version: tuple[int, int], system: str, machine: str, has_headers: bool, has_compiler: bool,
            demo: bool = False) -> str | None:  # fmt: skip
    """The one-line error for this Python, or None when it can set stewart_gym up (``demo``: the demo extra)."""
    here = f"Python {version[0]}.{version[1]}"
    if version < (3, 10):
        return f"error: stewart_gym needs Python 3.10 or newer, and this is {here}: run make with PYTHON=python3.11"
    wheel = system == "Linux" and machine == "x86_64" and version <= NEWEST_PYBULLET_WHEEL
    if wheel or (has_headers and has_compiler) or (demo and version > NEWEST_PYBULLET_WHEEL):
        return None
    missing = " and ".join(what for what, ok in (("the Python headers", has_headers), ("a C++ compiler", has_compiler))
                           if not ok)  # fmt: skip
    return (f"error: PyBullet has no wheel for {here} on {system} {machine}, so pip would compile it, and this "
            f"machine lacks {missing}: install them (Debian/Ubuntu: sudo apt install g++ "
            f"python{version[0]}.{version[1]}-dev), or run make with PYTHON=python3.11"
            + ("; make demo needs neither (it runs on MuJoCo here)" if version > NEWEST_PYBULLET_WHEEL else ""))


def main() -> int:
    include = sysconfig.get_paths()["include"]
    message = problem(sys.version_info[:2], platform.system(), platform.machine(),
                      os.path.exists(os.path.join(include, "Python.h")),
                      any(shutil.which(c) for c in ("c++", "g++", "clang++")), demo="--demo" in sys.argv[1:])  # fmt: skip
    if message:
        print(message, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
