"""The experiments the Control page reports: each is a module with ``run(argv)`` (the options as on its command
line; returns its report) and runs from the repository's root as ``python -m train.experiments.<name>``."""
