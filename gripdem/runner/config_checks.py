"""Checks of a composed config that need more than its schema: the split against the built-in
preset's simulations, rollout training against the split (the scene x model x data specifics
all run from :func:`gripdem.runner.config_schema.check_combination`, the one place that calls
them), and the split's windows against a user's file. Light: no torch, no Lightning."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from gripdem.data.protocols import (
    PLAN_OPTIONS,
    current_plan_names,
    plan_arguments,
    plan_windows,
)
from gripdem.data.windows import Split, resolve_rollout_links
from gripdem.runner.run_names import hydra_choices


def check_rollout_training(cfg: DictConfig, exact: bool) -> None:
    """``model.rollout``: a number of links the split's horizon holds (one line naming the
    option and what is allowed, before any data is read), on a point forecast in the exact
    frame."""
    split = Split(int(cfg.split.history), int(cfg.split.horizon))
    link = cfg.data.get("model_horizon")
    link = split.horizon if link is None else min(int(link), split.horizon)
    links = resolve_rollout_links(cfg.model.rollout.links, split.horizon, link)
    start = float(cfg.model.rollout.start)
    if not 0.0 <= start < 1.0:
        raise ValueError(
            "model.rollout.start is the fraction of the training budget trained on one link "
            f"before the links are chained, in [0, 1), got {start:g}"
        )
    if links > 1 and (cfg.model.loss != "mse" or not exact):
        raise ValueError(
            f"model.rollout.links={links} trains point forecasts in the exact frame "
            f"(model.loss=mse, model.encoding=unwrapped), got model.loss={cfg.model.loss}, "
            f"model.encoding={cfg.model.encoding.value}: use model.rollout.links=1"
        )


def check_split_fits_the_preset(cfg: DictConfig) -> None:
    """The built-in dataset's simulations hold the split's h+1+f frames: a split given on the
    command line with a preset's smaller scene (``experiment=smoke`` chooses ``preset=tiny``)
    is refused here, naming both, before any data is generated."""
    if cfg.data.get("path") is not None or "frames" not in cfg.preset:
        return
    needed = int(cfg.split.history) + 1 + int(cfg.split.horizon)
    frames = int(cfg.preset.frames)
    if needed <= frames:
        return
    choices = hydra_choices(cfg)
    preset = f"preset={choices.get('preset', cfg.preset.get('name'))}"
    experiment = choices.get("experiment")
    if experiment:
        preset += f" (the size experiment={experiment} runs at)"
    raise ValueError(
        f"split={cfg.split.name} needs simulations of {needed} frames (h+1+f) but {preset} "
        f"writes {frames} per simulation: give preset=default, or a split of at most "
        f"{frames} frames (e.g. split=10-5)"
    )


def check_windows_fit_the_file(path: Path, data: dict, split: Split) -> None:
    """The split's windows fit a user's file (``data.path``): the DataModule's own window plan
    (:func:`gripdem.data.protocols.plan_windows`, from the same ``data`` options as plain
    values, so the same one-line error), made from the shape of the file's positions before
    ``python -m gripdem.run`` imports Lightning (seconds). A file that cannot be read this way
    is left to the load, which names what is wrong with it."""
    import h5py

    try:
        with h5py.File(path, "r") as h5:
            shape = h5["positions"].shape
    except (OSError, KeyError, TypeError):
        return
    if len(shape) != 4:
        return
    data = current_plan_names(data)  # a run's config saved before the rename
    options = {key: data[key] for key in PLAN_OPTIONS if data.get(key) is not None}
    plan_windows(int(shape[0]), int(shape[1]), split, **plan_arguments(**options))
