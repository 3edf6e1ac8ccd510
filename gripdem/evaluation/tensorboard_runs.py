"""What TensorBoard shows of a log folder, read with TensorBoard's own reader.

:func:`read_runs` loads every run under a log folder the way ``tensorboard --logdir`` does
(``EventMultiplexer``: a run is a folder holding event files, named by its path relative to the
log folder) and returns, per run, the scalar tags with their (step, value) points and the
HParams plugin's session record (hyperparameters with their protobuf types). It is how the tests
and ``experiments/tensorboard/screenshots.py`` check what a researcher will see, without a
browser.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class RunView:
    """One TensorBoard run: its name, scalar series and HParams session values."""

    name: str
    scalars: dict[str, list[tuple[int, float]]] = field(default_factory=dict)
    #: ``{hparam: value}``, each value of its protobuf kind (bool, float or str)
    hparams: dict[str, Any] = field(default_factory=dict)
    #: the HParams row's name (its Trial ID; empty: the run's name)
    trial: str = ""
    #: whether the run carries an HParams experiment summary (columns fixed by one run)
    has_experiment_tag: bool = False
    images: list[str] = field(default_factory=list)


def read_runs(logdir: str | os.PathLike) -> dict[str, RunView]:
    """``{run name: RunView}`` of every run under ``logdir`` (TensorBoard's run names)."""
    from tensorboard.backend.event_processing import event_multiplexer
    from tensorboard.plugins.hparams import metadata as hparams_metadata

    logdir = Path(logdir)
    if not logdir.is_dir():
        raise FileNotFoundError(f"{logdir}: no such log folder")
    multiplexer = event_multiplexer.EventMultiplexer(
        size_guidance={"scalars": 0, "tensors": 0, "images": 1}
    )
    multiplexer.AddRunsFromDirectory(str(logdir))
    multiplexer.Reload()
    hparams_content = multiplexer.PluginRunToTagToContent(hparams_metadata.PLUGIN_NAME)
    runs: dict[str, RunView] = {}
    for name in sorted(multiplexer.Runs()):
        accumulator = multiplexer.GetAccumulator(name)
        view = RunView(name=name)
        tags = accumulator.Tags()
        for tag in tags.get("scalars", []):
            view.scalars[tag] = [(e.step, e.value) for e in accumulator.Scalars(tag)]
        content = hparams_content.get(name, {})
        view.has_experiment_tag = hparams_metadata.EXPERIMENT_TAG in content
        if hparams_metadata.SESSION_START_INFO_TAG in content:
            start = hparams_metadata.parse_session_start_info_plugin_data(
                content[hparams_metadata.SESSION_START_INFO_TAG]
            )
            view.hparams = {k: _value(v) for k, v in start.hparams.items()}
            view.trial = start.group_name
        view.images = list(tags.get("images", []))
        runs[name] = view
    return runs


def _value(value) -> Any:
    kind = value.WhichOneof("kind")
    if kind == "bool_value":
        return bool(value.bool_value)
    if kind == "number_value":
        return float(value.number_value)
    if kind == "string_value":
        return str(value.string_value)
    return None


def describe(runs: dict[str, RunView]) -> str:
    """A plain-text account: run names, HParams keys with types, scalar tag counts."""
    lines = [f"{len(runs)} run(s)"]
    for name, view in runs.items():
        single = sum(1 for points in view.scalars.values() if len(points) == 1)
        lines.append(
            f"- run {name!r}: {len(view.scalars)} scalar tags ({single} with one point), "
            f"{len(view.images)} image tags, HParams row {view.trial or name!r}, "
            f"experiment tag: {view.has_experiment_tag}"
        )
        typed = ", ".join(f"{k}: {type(v).__name__}={v!r}" for k, v in view.hparams.items())
        lines.append(f"  hparams: {typed}")
        hp = {k: v[-1][1] for k, v in view.scalars.items() if k.startswith("hp/")}
        lines.append(f"  hp/ metrics: {hp}")
    return "\n".join(lines)
