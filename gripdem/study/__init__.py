"""Hyperparameter studies: Optuna studies that are stored, resumed, pruned and run
asynchronously, on one machine or as workers of a cluster (``hparams_search=optuna``).

- :mod:`gripdem.study.space`: the search space, from ``hydra.sweeper.params`` (Hydra's sweep
  grammar) to Optuna distributions and back to overrides;
- :mod:`gripdem.study.storage`: where a study lives (a journal file by default, any Optuna
  storage URL), opening, creating and resuming it with its space checked, the heartbeat of
  running trials and the re-queue of trials whose process died;
- :mod:`gripdem.study.sweeper`: the Hydra sweeper (``hydra/sweeper=study``): a new trial as soon
  as a slot frees, through whichever Hydra launcher is configured;
- :mod:`gripdem.study.trial`: inside a trial's run: its heartbeat, its validation reports and
  the pruner's verdict, its end told to the study.

Only the trial's run imports Lightning; the study's controlling process imports Optuna and Hydra.
"""
