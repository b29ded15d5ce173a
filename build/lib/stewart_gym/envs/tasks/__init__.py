"""The built-in tasks: balance, track and disturbance (one file each; see :mod:`stewart_gym.envs.task`)."""
