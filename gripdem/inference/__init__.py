"""Inference: a trained model applied to data it has not seen. Checkpoints (loaded as data,
checked against the dataset's scene), chained rollouts of any length with divergence checks,
and the pipeline of ``python -m gripdem.predict`` (observed frames in, predictions, trajectory
and per-frame report out, every baseline beside the model).
"""
