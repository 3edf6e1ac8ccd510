"""The experiment runner behind ``python -m gripdem.run``: the Hydra config schema (typos fail
while composing), one experiment (resolve or generate the data, train with Lightning, test out of
sample beside the baselines, write logs, predictions, figures and metrics), the checkpoint that
makes ``resume=true`` continue a killed run exactly (``resume``), the multirun summary callback
and the console set-up (each log line once, no dependency noise).
"""
