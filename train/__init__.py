"""Training recipes (``sweeps/``), the tools that keep the shipped policies and the Control page (``tools/``), and
the experiments reported there (``experiments/``). Not part of the installed package."""
