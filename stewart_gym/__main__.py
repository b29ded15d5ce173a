"""``python -m stewart_gym``: the ``stewart-gym`` command line."""

from stewart_gym.cli import main

if __name__ == "__main__":  # worker processes (forkserver, spawn) import this module too: run only when asked
    raise SystemExit(main())
