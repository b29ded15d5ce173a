"""Train an agent: ``python train/train.py --env StewartBallBalance-v0 --algo ppo [options]``.

The same as ``stewart-gym train``; see ``stewart_gym.training`` for the run folder layout.
"""

from __future__ import annotations

import sys

from stewart_gym.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
