"""gripdem's Hydra plugins: the parallel launcher (the jobs of a multirun side by side, each in
its own process: :mod:`gripdem.runner.parallel_launcher`) and the study sweeper (stored,
resumable, pruned, asynchronous Optuna studies: :mod:`gripdem.study.sweeper`). Hydra finds
plugin classes in the ``hydra_plugins`` namespace only, so this package holds the classes and
their configs; the work is in ``gripdem``."""
