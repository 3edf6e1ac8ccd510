"""A trained run's checkpoint applied to new data: compatibility, loading, in-sample check.

A checkpoint of :class:`~gripdem.models.module.TrajectoryModule` holds in its hyperparameters
the scene it was trained on (box, boundary, shear rate, LE sign and time origin, diameter,
frame interval), the encoding, the normaliser, the history length and horizon, the graph
cut-off and the fitted linear AR baseline. :func:`check_compatible` decides whether a dataset
is a scene the model can be applied to, and refuses the rest with an
:class:`IncompatibleError` naming the data file, the field and the checkpoint:

- same boundary kind, particle diameter and frame interval (relative tolerance
  ``SCENE_RTOL``), and in a sheared box the same signed shear rate (the flow direction);
- the same box, except for models that read relative geometry only (the exact frame,
  ``encoding=unwrapped``, with the ``grip`` decoder, in a sheared box, without x-position
  features): those are applied in the data's box;
- the paper's dense n x n graph (``trainable_graph=dense``) only at its own particle count.

The LE time origin and sign convention of the data are the data's own: :func:`load_model`
builds the model with the data's scene, so decoding wraps each frame with the data's offsets.

Loading is safe for files from anyone (:func:`read_checkpoint`): a Lightning ``.ckpt`` is
unpickled with ``torch.load(weights_only=True)`` only (tensors and plain containers; a file
that needs any other class or function is refused before anything in it runs), after a check
that its zip records are stored as ``torch.save`` writes them (uncompressed, so no record can
expand beyond the file); a ``.safetensors`` model file (:mod:`gripdem.inference.model_file`)
holds no pickle at all. Either way the model is built as ``TrajectoryModule(**hparams)`` and
the weights loaded with ``strict=True``. Refusals are :class:`CheckpointError` naming the file.
"""

from __future__ import annotations

import json
import os
import pickle
import re
import warnings
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

import gripdem
from gripdem.data.encodings import ENCODINGS
from gripdem.data.schema import DatasetMeta
from gripdem.inference.model_file import (
    CheckpointError,
    build_module,
    check_hparams,
    finite_metrics,
    is_safetensors,
    read_model_file,
    save_model_file,
)
from gripdem.inference.pretrained import resolve as resolve_pretrained

__all__ = [
    "CheckpointError",
    "IncompatibleError",
    "check_compatible",
    "export_run_model",
    "load_checkpoint_model",
    "load_model",
    "read_checkpoint",
    "read_hparams",
    "training_overlap",
]

#: diameter, frame interval and shear rate must agree within this relative tolerance
SCENE_RTOL = 1e-3
#: box lengths agree within this relative tolerance
BOX_RTOL = 1e-6


class IncompatibleError(ValueError):
    """A checkpoint that cannot be applied to a dataset: names the data, field and checkpoint."""

    def __init__(self, data: Path, checkpoint: Path, field: str, message: str):
        super().__init__(f"{data}: field '{field}': {message} (checkpoint {checkpoint})")


def _check_zip(path: Path) -> None:
    """A torch zip checkpoint whose records are stored uncompressed (as ``torch.save`` writes
    them) and lie within the file: no record can expand in memory beyond the file's size."""
    size = path.stat().st_size
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise CheckpointError(
            path, "<file>", f"not a readable PyTorch checkpoint (a broken zip: {exc})"
        ) from None
    for info in members:
        if info.compress_type != zipfile.ZIP_STORED or info.file_size > size:
            raise CheckpointError(
                path,
                info.filename,
                f"a compressed or oversized record ({info.file_size} bytes in a {size}-byte "
                "file); torch.save stores records uncompressed: a crafted file?",
            )


def _read_lightning(path: Path) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    _check_zip(path)
    try:
        with warnings.catch_warnings():  # torch's remarks on a foreign file: the error says it
            warnings.simplefilter("ignore", UserWarning)
            content = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        found = re.search(r"(unsupported|Unsupported) (global: )?GLOBAL ([\w.]+)", str(exc))
        reason = f"it asks for {found.group(3)}" if found else "it is not plain data"
        raise CheckpointError(
            path,
            "<pickle>",
            "refused by the safe loader (weights_only): the file needs classes or functions "
            f"that a gripdem checkpoint never holds, and nothing in it was run ({reason})",
        ) from None
    except Exception as exc:  # torch raises many kinds for a file that is not a checkpoint
        raise CheckpointError(
            path, "<file>", f"not a readable PyTorch checkpoint ({type(exc).__name__}: {exc})"
        ) from None
    if not isinstance(content, Mapping):
        raise CheckpointError(path, "<file>", f"expected a dict, got {type(content).__name__}")
    hparams = check_hparams(path, content.get("hyper_parameters"))
    state = content.get("state_dict")
    if not isinstance(state, Mapping) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
    ):
        raise CheckpointError(path, "state_dict", "expected a mapping of names to tensors")
    return hparams, dict(state)


def read_checkpoint(
    checkpoint: str | os.PathLike, tensors: bool = True
) -> tuple[dict[str, Any], dict[str, torch.Tensor], dict[str, Any]]:
    """``(hparams, state_dict, card)`` of a Lightning ``.ckpt`` or a ``.safetensors`` model
    file, read safely (see the module doc; the card of a ``.ckpt`` is empty). ``pretrained:NAME``
    names a model shipped with gripdem (:mod:`gripdem.inference.pretrained`)."""
    path = resolve_pretrained(checkpoint)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such checkpoint")
    if not path.is_file():
        raise CheckpointError(path, "<file>", "expected a checkpoint file, got a folder")
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head.startswith(b"PK\x03\x04") or zipfile.is_zipfile(path):  # a (maybe broken) zip
        hparams, state = _read_lightning(path)
        return hparams, state, {}
    if is_safetensors(path):
        return read_model_file(path, tensors)
    raise CheckpointError(
        path,
        "<file>",
        f"not a readable PyTorch checkpoint: expected a Lightning .ckpt (a zip file) or a "
        f"gripdem .safetensors model file, found a file starting with {head!r}",
    )


def read_hparams(checkpoint: str | os.PathLike) -> dict[str, Any]:
    """The hyperparameters of a gripdem checkpoint (a clear error for anything else)."""
    return read_checkpoint(checkpoint, tensors=False)[0]


def load_checkpoint_model(checkpoint: str | os.PathLike):
    """The model of a ``.ckpt`` or ``.safetensors`` file as trained (eval mode, CPU)."""
    hparams, state, _ = read_checkpoint(checkpoint)
    return build_module(checkpoint, hparams, state)


def export_run_model(
    model, path: str | os.PathLike, run: Mapping[str, Any], metrics: Mapping[str, Any]
) -> Path:
    """Write ``model`` as a shareable model file with its card: the run's flat
    hyperparameters ``run`` (scene, split, model, ...), the test metrics, gripdem's version."""
    card = {
        "gripdem_version": gripdem.__version__,
        "scene": run.get("scene"),
        "split": run.get("split"),
        "model": run.get("model"),
        "run": dict(run),
        "metrics": finite_metrics(metrics),
    }
    return save_model_file(model, path, card, overwrite=True)


def data_scene(meta: DatasetMeta) -> dict[str, Any]:
    """The ``scene`` hyperparameter of a model trained on, or applied to, ``meta``'s data."""
    attrs = meta.boundary.to_attrs()
    return {
        **{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in attrs.items()},
        "diameter": meta.diameter,
        "frame_interval": meta.frame_interval,
        "body_force_amplitude": meta.body_force_amplitude,
    }


def _close(a: float, b: float, rtol: float) -> bool:
    return abs(a - b) <= rtol * max(abs(a), abs(b))


def check_compatible(checkpoint, meta: DatasetMeta) -> tuple[dict[str, Any], list[str]]:
    """The checkpoint's hyperparameters if it can be applied to ``meta``'s data, and notes on
    what differs harmlessly; raises :class:`IncompatibleError` otherwise."""
    checkpoint = Path(checkpoint)
    hp = read_hparams(checkpoint)
    scene, data, notes = hp["scene"], data_scene(meta), []

    def fail(field: str, message: str) -> IncompatibleError:
        return IncompatibleError(meta.path, checkpoint, field, message)

    if hp["encoding"] not in ENCODINGS:
        raise fail("encoding", f"the model's encoding {hp['encoding']!r} is unknown here")
    if scene["boundary"] != data["boundary"]:
        raise fail(
            "boundary",
            f"the model was trained on {scene['boundary']!r} data, the file holds "
            f"{data['boundary']!r}",
        )
    for key, what in (("diameter", "particle diameter"), ("frame_interval", "frame interval")):
        if not _close(float(scene[key]), float(data[key]), SCENE_RTOL):
            raise fail(
                key,
                f"the model was trained with {what} {scene[key]:.6g}, the data has "
                f"{data[key]:.6g} (relative tolerance {SCENE_RTOL:g}): it predicts one frame "
                "of that scene per step",
            )
    if "body_force_amplitude" in scene and not _close(
        float(scene["body_force_amplitude"]), float(data["body_force_amplitude"]), SCENE_RTOL
    ):
        raise fail(
            "body_force_amplitude",
            f"the model was trained with the body force a = {scene['body_force_amplitude']:.6g} "
            f"m/s^2 (a_z = a cos(2 pi x / lx)), the data has {data['body_force_amplitude']:.6g}: "
            "another drive, another flow",
        )
    sheared = data["boundary"] == "lees_edwards"
    if sheared:
        trained = float(scene["le_sign"]) * float(scene["shear_rate"])
        given = float(data["le_sign"]) * float(data["shear_rate"])
        if not _close(trained, given, SCENE_RTOL):
            hint = (
                " (opposite flow directions: mirror the data's z axis, or convert it with the "
                "other --le-sign)"
                if trained * given < 0
                else ""
            )
            raise fail(
                "shear_rate",
                f"the model was trained at signed shear rate {trained:+.6g} (le_sign x "
                f"shear_rate), the data has {given:+.6g}{hint}",
            )
        if not _close(float(scene["le_time_origin"]), float(data["le_time_origin"]), 1e-12):
            notes.append(
                f"LE time origin: the data's {data['le_time_origin']:.6g} is used (the model "
                f"was trained with {scene['le_time_origin']:.6g}; offsets follow the data)"
            )
    encoder = dict(hp.get("encoder") or {})
    box_model, box_data = np.asarray(scene["box"]), np.asarray(data["box"])
    if np.abs(box_model - box_data).max() > BOX_RTOL * box_model.max():
        relative_only = (
            hp["encoding"] == "unwrapped"
            and hp.get("decoder_mode") == "grip"
            and sheared
            and str(encoder.get("position_features", "auto")).lower() != "true"
        )
        if not relative_only:
            raise fail(
                "box",
                f"the model was trained in a box {box_model.tolist()}, the data's is "
                f"{box_data.tolist()}: this model ({hp['encoding']} encoding, "
                f"{hp.get('decoder_mode')} decoder, {data['boundary']}) depends on the box; only "
                "exact-frame grip models of a sheared scene are applied in another box",
            )
        notes.append(
            f"box: applied in the data's box {box_data.tolist()} (trained in "
            f"{box_model.tolist()}; the model reads relative geometry only)"
        )
    if encoder.get("name", "graph_conv") == "graph_conv" and encoder.get("trainable_graph") == (
        "dense"
    ):
        n = hp.get("n_particles")
        if n != meta.n_particles:
            raise fail(
                "positions",
                f"the model's dense n x n graph (trainable_graph=dense) was trained for {n} "
                f"particles, the data has {meta.n_particles}; the sparse edge graph "
                "(trainable_graph=edge) transfers across particle counts",
            )
    return hp, notes


def load_model(checkpoint, meta: DatasetMeta):
    """The model of ``checkpoint`` with the data's scene (after :func:`check_compatible`)."""
    hparams, state, _ = read_checkpoint(checkpoint)
    return build_module(checkpoint, hparams, state, scene=data_scene(meta))


def _same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def training_overlap(
    checkpoint, data_path, sims: list[int], first_target: int
) -> tuple[bool, str, str]:
    """Is the prediction in sample? ``(in_sample, protocol label, note)``.

    Reads the run's ``metrics.json`` next to ``checkpoints/`` (the data file and the training
    simulations or time boundaries). In sample: the same file and a training simulation
    (protocol ``sims``/``paper``) or, under ``time``, a predicted frame before the end of the
    training targets. Labelled ``paper`` (the in-sample protocol of ``predictions.h5``) then,
    else ``sims`` or ``time``."""
    metrics = Path(checkpoint).resolve().parent.parent / "metrics.json"
    if not metrics.exists():
        return (
            False,
            "sims",
            (
                f"in-sample check: {metrics} not found, so the training data is unknown; the "
                "predictions are labelled out of sample"
            ),
        )
    try:
        summary = json.loads(metrics.read_text()).get("data", {})
    except json.JSONDecodeError:
        summary = {}
    trained_on = summary.get("path")
    if not trained_on or not _same_file(trained_on, data_path):
        return False, "sims", f"out of sample: the model was trained on {trained_on}"
    protocol = summary.get("protocol", "sims")
    shared = sorted(set(sims) & set(summary.get("sims_train", [])))
    if protocol == "time" and shared:
        boundary = int(summary.get("time_boundaries", [0])[0])
        if first_target < boundary:
            return (
                True,
                "paper",
                (
                    f"IN SAMPLE: predicted frames from {first_target} on; the model trained on "
                    f"targets before frame {boundary} of simulations {shared}"
                ),
            )
        return False, "time", f"out of sample in time: training targets end before {boundary}"
    if shared:
        return True, "paper", f"IN SAMPLE: simulations {shared} were training simulations"
    validation = sorted(set(sims) & set(summary.get("sims_val", [])))
    if validation:
        return (
            False,
            "sims",
            (f"out of sample, but simulations {validation} chose the checkpoint (validation)"),
        )
    return False, "sims", f"out of sample: simulations {sims} were not trained on"
