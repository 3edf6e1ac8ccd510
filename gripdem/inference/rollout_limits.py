"""Where a rollout counts as diverged: the thresholds of its divergence checks
(:mod:`gripdem.inference.rollout`), in a module that imports nothing heavy, so that the CLI's
``--help`` can show them without importing torch."""

#: a predicted step longer than this fraction of the smallest box length counts as an escape
ESCAPE_FRACTION = 0.25
#: default: flag overlap once this many more particles overlap than at the observed frame
OVERLAP_MARGIN = 0.05
