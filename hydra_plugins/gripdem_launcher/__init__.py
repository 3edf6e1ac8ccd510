"""gripdem's Hydra launcher plugin: the jobs of a multirun side by side, each in its own process
(the work is :mod:`gripdem.runner.parallel_launcher`; Hydra loads launcher classes from the
``hydra_plugins`` namespace only, so this package holds the class and its config)."""
