"""Is a prediction in sample? What trained a model, read from its run or from its card.

``python -m gripdem.predict`` labels its predictions in or out of sample. Two records say what
trained a model, read in this order:

1. the run's ``metrics.json`` (a model in the ``checkpoints/`` folder of a
   ``python -m gripdem.run`` output): the data file's path and the split plan;
2. the model file's card (``.safetensors``; ``pretrained:NAME`` is resolved to the shipped file
   first): ``training_data`` names the file, its sizes and its provenance and, in files written
   since it does, the split plan under ``training_data.split``
   (:func:`gripdem.inference.checkpoint.training_data_card`).

The data file is the training data when it is the run's file, or, by the card, when its sizes
and its provenance's identity (:func:`data_identity`: the generator and its parameters, seed
included; not wall times) equal the card's, whatever the file is called. Then the split plan
decides: in sample when a predicted simulation trained the model (protocols ``sims`` and
``paper``) or, under ``time``, when a predicted frame lies before the end of the training
targets. In-sample predictions are labelled ``paper`` (the in-sample protocol of
``predictions.h5``), the others ``sims`` or ``time``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from gripdem.data.dataset_io import read_meta
from gripdem.inference.model_file import is_safetensors, read_model_file
from gripdem.inference.pretrained import resolve as resolve_pretrained

#: ``(in_sample, protocol label, note)``
Overlap = tuple[bool, str, str]
#: the predictions' label when nothing shows that they are in sample
UNKNOWN = "the predictions are labelled out of sample"


def data_identity(provenance: Mapping[str, Any]) -> dict[str, Any]:
    """What identifies a dataset in its provenance: the generator and its parameters (its
    configuration, seed included); a provenance without parameters, all of it but the wall
    times. Empty: nothing identifies the data."""
    if "parameters" in provenance:
        return {"generator": provenance.get("generator"), "parameters": provenance["parameters"]}
    return {key: value for key, value in provenance.items() if key != "wall_time_s"}


def described(data: Mapping[str, Any]) -> str:
    """``file, generator seed S`` of a card's training data."""
    provenance = data.get("provenance") or {}
    seed = (provenance.get("parameters") or {}).get("seed", provenance.get("seed"))
    text = f"{data.get('file')}, {provenance.get('generator')}"
    return text if seed is None else f"{text} seed {seed}"


def split_verdict(
    split: Mapping[str, Any], sims: Sequence[int], first_target: int, source: str = ""
) -> Overlap:
    """The verdict on predicting ``sims`` from frame ``first_target`` on in the training data,
    by the split plan ``split`` (``protocol``, ``sims_train``, ``sims_val``,
    ``time_boundaries``); ``source`` ends each note (e.g. `` (per its card)``)."""
    protocol = split.get("protocol", "sims")
    shared = sorted(set(sims) & set(split.get("sims_train", [])))
    if protocol == "time" and shared:
        boundary = int(split.get("time_boundaries", [0])[0])
        if first_target < boundary:
            return (
                True,
                "in_sample",
                f"IN SAMPLE: predicted frames from {first_target} on; the model trained on "
                f"targets before frame {boundary} of simulations {shared}{source}",
            )
        return (
            False,
            "time",
            f"out of sample in time: training targets end before {boundary}{source}",
        )
    if shared:
        return (
            True,
            "in_sample",
            f"IN SAMPLE: simulations {shared} were training simulations of this model{source}",
        )
    validation = sorted(set(sims) & set(split.get("sims_val", [])))
    if validation:
        return (
            False,
            "sims",
            f"out of sample, but simulations {validation} chose the checkpoint "
            f"(validation){source}",
        )
    return False, "sims", f"out of sample: simulations {list(sims)} were not trained on{source}"


def _same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def run_summary(model: Path) -> dict[str, Any] | None:
    """The data summary of the run whose ``checkpoints/`` folder holds ``model`` (its
    ``metrics.json``), or None: not in a run's folder, or no readable record of the data."""
    if model.resolve().parent.name != "checkpoints":
        return None
    metrics = model.resolve().parent.parent / "metrics.json"
    try:
        summary = json.loads(metrics.read_text()).get("data")
    except (OSError, json.JSONDecodeError, AttributeError):
        return None
    return summary if isinstance(summary, dict) and summary.get("path") else None


def card_verdict(
    data: Mapping[str, Any], data_path, sims: Sequence[int], first_target: int
) -> Overlap:
    """The verdict by a model card's ``training_data`` (see the module doc)."""
    name = described(data)
    identity = data_identity(data.get("provenance") or {})
    if not identity:
        return (
            False,
            "sims",
            f"in-sample check: the model's card names its training data ({data.get('file')}) "
            f"without its provenance, so no file can be matched to it; {UNKNOWN}",
        )
    meta = read_meta(data_path)
    sizes = (meta.n_sims, meta.n_frames, meta.n_particles)
    trained = tuple(data.get(key) for key in ("simulations", "frames", "particles"))
    if data_identity(meta.provenance) != identity or sizes != trained:
        return (
            False,
            "sims",
            f"out of sample: the model's card names its training data ({name}); this file is "
            "another dataset",
        )
    split = data.get("split")
    if not split:
        return (
            False,
            "sims",
            f"in-sample check: this file is the model's training data ({name}, per its card), "
            f"but the card does not say which simulations trained it; {UNKNOWN}",
        )
    return split_verdict(split, sims, first_target, " (per its card)")


def training_overlap(checkpoint, data_path, sims: Sequence[int], first_target: int) -> Overlap:
    """Is the prediction of ``sims`` from frame ``first_target`` on of ``data_path`` in
    sample? ``(in_sample, protocol label, note)`` by the run's ``metrics.json``, else by the
    model file's card (see the module doc)."""
    model = resolve_pretrained(checkpoint)
    summary = run_summary(model)
    if summary is not None:
        if not _same_file(summary["path"], data_path):
            return False, "sims", f"out of sample: the model was trained on {summary['path']}"
        return split_verdict(summary, sims, first_target)
    if not is_safetensors(model):
        return (
            False,
            "sims",
            f"in-sample check: {model} has no run metrics.json beside it (a run's "
            f"checkpoints/ folder) and no model card, so the training data is unknown; {UNKNOWN}",
        )
    data = read_model_file(model, tensors=False)[2].get("training_data")
    if not isinstance(data, Mapping):
        return (
            False,
            "sims",
            f"in-sample check: the model file's card names no training data; {UNKNOWN}",
        )
    return card_verdict(data, data_path, sims, first_target)
