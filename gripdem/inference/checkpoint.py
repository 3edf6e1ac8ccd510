"""A trained run's checkpoint applied to new data: compatibility, loading, its model card.

A checkpoint of :class:`~gripdem.models.module.TrajectoryModule` holds in its hyperparameters
the scene it was trained on (box, boundary, shear rate, LE sign and time origin, diameter,
frame interval), the encoding, the normaliser, the history length and horizon, the graph
cut-off and the fitted linear AR baseline. :func:`check_compatible` decides whether a dataset
is a scene the model can be applied to as it is (``purpose="apply"``: ``predict``, the Python
API) or fine-tuned on (``purpose="finetune"``: the runner's ``model.init_from``), and refuses
the rest with an :class:`IncompatibleError` naming the data file, the field and the checkpoint.
The rule is stated once for users in ``docs/reference/rules.md``; applied as it is:

- the same boundary kind, and in a sheared box the same flow direction (sign of the signed
  shear rate);
- box, particle diameter, frame interval, shear rate and body-force amplitude within
  ``SCENE_TOLERANCE`` (1 %) of the training scene's, each difference printed as a note
  (:mod:`gripdem.inference.scene_match`: every model's inputs are dimensionless; which depends
  on which parameter); models that read relative geometry only (the exact frame,
  ``encoding=unwrapped``, with the ``grip`` decoder, in a sheared box, without x-position
  features) are applied in any box;
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

from gripdem._version import __version__
from gripdem.data.encodings import ENCODINGS
from gripdem.data.schema import DatasetMeta
from gripdem.errors import IncompatibleError
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
from gripdem.inference.scene_match import SCENE_TOLERANCE, compare

__all__ = [
    "SCENE_TOLERANCE",
    "CheckpointError",
    "IncompatibleError",
    "SPLIT_KEYS",
    "FINETUNE_BEYOND",
    "PURPOSES",
    "check_compatible",
    "export_run_model",
    "training_data_card",
    "load_checkpoint_model",
    "load_model",
    "read_checkpoint",
    "read_hparams",
]


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


#: what a model card keeps of the split plan (:meth:`gripdem.data.protocols.WindowPlan.summary`):
#: which simulations (and, under ``time``, which frames) trained, validated and tested the model
SPLIT_KEYS = ("split", "protocol", "sims_train", "sims_val", "sims_test", "time_boundaries")


def training_data_card(meta: DatasetMeta, split: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """What a model card says about the training data: the file's name, its sizes and scene,
    its provenance (the generator and the configuration that made it, or the importer and its
    options) and, given the split plan's ``split`` (``WindowPlan.summary()`` or the data
    module's summary), its :data:`SPLIT_KEYS` under ``split``: the in-sample check of a model
    file away from its run (:mod:`gripdem.inference.in_sample`) reads them."""
    card = {
        "file": Path(meta.path).name,
        "simulations": int(meta.n_sims),
        "frames": int(meta.n_frames),
        "particles": int(meta.n_particles),
        "scene": data_scene(meta),
        "provenance": dict(meta.provenance),
    }
    if split is not None:
        card["split"] = {key: split[key] for key in SPLIT_KEYS if key in split}
    return card


def export_run_model(
    model,
    path: str | os.PathLike,
    run: Mapping[str, Any],
    metrics: Mapping[str, Any],
    meta: DatasetMeta | None = None,
    split: Mapping[str, Any] | None = None,
) -> Path:
    """Write ``model`` as a shareable model file with its card: the run's flat
    hyperparameters ``run`` (scene, split, model, ...), the test metrics, gripdem's version and
    (given the training data's ``meta``, and the split plan's summary ``split``)
    :func:`training_data_card`."""
    card = {
        "gripdem_version": __version__,
        "scene": run.get("scene"),
        "split": run.get("split"),
        "model": run.get("model"),
        "run": dict(run),
        "metrics": finite_metrics(metrics),
    }
    if meta is not None:
        card["training_data"] = training_data_card(meta, split)
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


def _relative_only(hp: dict[str, Any], sheared: bool) -> bool:
    """Exact-frame grip models of a sheared scene without x-position features read relative
    geometry only: they are applied in any box."""
    encoder = dict(hp.get("encoder") or {})
    return (
        hp["encoding"] == "unwrapped"
        and hp.get("decoder_mode") == "grip"
        and sheared
        and str(encoder.get("position_features", "auto")).lower() != "true"
    )


#: what a model is used for on other data: applied as it is (``predict``, the Python API, a
#: surrogate run) or fine-tuned on it (``model.init_from``)
PURPOSES = ("apply", "finetune")
#: why a scene beyond the tolerance is accepted for fine-tuning
FINETUNE_BEYOND = (
    "fine-tuning adapts the model to this scene (its as-it-is test row lies outside its "
    "training scene)"
)


def check_compatible(
    checkpoint, meta: DatasetMeta, purpose: str = "apply"
) -> tuple[dict[str, Any], list[str]]:
    """The checkpoint's hyperparameters if it can be used on ``meta``'s data for ``purpose``,
    and notes on what differs from its training scene; raises :class:`IncompatibleError`
    otherwise. The one rule for a model on other data (``docs/reference/rules.md``), called by
    ``gripdem.predict``, the Python API and the runner's fine-tuning alike.

    ``purpose="apply"`` (the model as it is): box, diameter, frame interval, shear rate and
    body-force amplitude may differ from the training scene's by
    :data:`~gripdem.inference.scene_match.SCENE_TOLERANCE` (1 %): every model reads
    dimensionless inputs, and within 1 % of the training scene they move less than between two
    simulations of that scene (:mod:`gripdem.inference.scene_match` says which input depends on
    which parameter). Each difference is a note; beyond the tolerance the field is refused
    with both values (the exception: exact-frame ``grip`` models of a sheared scene without
    x-position features read relative geometry only and are applied in any box).

    ``purpose="finetune"`` (``model.init_from``): the same parameters may differ by any
    amount, each difference beyond the tolerance noted; fine-tuning is how a model reaches
    another scene.

    Always refused, for either purpose: an unknown encoding, another boundary kind, the
    opposite flow direction, the dense n x n graph at another particle count.

    :raises IncompatibleError: (a ``ValueError``) naming the data file, the field, both values
        and the checkpoint.
    :raises CheckpointError: the checkpoint cannot be read safely.
    :raises ValueError: ``purpose`` is not one of :data:`PURPOSES`."""
    if purpose not in PURPOSES:
        raise ValueError(f"purpose={purpose!r}: expected one of {PURPOSES}")
    checkpoint = Path(checkpoint)
    hp = read_hparams(checkpoint)
    scene, data, notes = hp["scene"], data_scene(meta), []
    finetune = FINETUNE_BEYOND if purpose == "finetune" else None

    def fail(field: str, message: str) -> IncompatibleError:
        return IncompatibleError(meta.path, checkpoint, field, message)

    def add(note: str | None) -> None:
        if note is not None:
            notes.append(note)

    if hp["encoding"] not in ENCODINGS:
        raise fail("encoding", f"the model's encoding {hp['encoding']!r} is unknown here")
    if scene["boundary"] != data["boundary"]:
        raise fail(
            "boundary",
            f"the model was trained on {scene['boundary']!r} data, the file holds "
            f"{data['boundary']!r}",
        )
    for key in ("diameter", "frame_interval"):
        add(compare(key, float(scene[key]), float(data[key]), fail, beyond_ok=finetune))
    if "body_force_amplitude" in scene:
        key = "body_force_amplitude"
        add(compare(key, float(scene[key]), float(data[key]), fail, beyond_ok=finetune))
    sheared = data["boundary"] == "lees_edwards"
    if sheared:
        trained = float(scene["le_sign"]) * float(scene["shear_rate"])
        given = float(data["le_sign"]) * float(data["shear_rate"])
        if trained * given < 0:
            raise fail(
                "shear_rate",
                f"the model was trained at signed shear rate {trained:+.6g} (le_sign x "
                f"shear_rate), the data has {given:+.6g} (opposite flow directions: mirror the "
                "data's z axis, or convert it with the other --le-sign)",
            )
        add(compare("shear_rate", trained, given, fail, beyond_ok=finetune))
        if not _close(float(scene["le_time_origin"]), float(data["le_time_origin"]), 1e-12):
            notes.append(
                f"LE time origin: the data's {data['le_time_origin']:.6g} is used (the model "
                f"was trained with {scene['le_time_origin']:.6g}; offsets follow the data)"
            )
    relative = _relative_only(hp, sheared)
    add(
        compare(
            "box",
            [float(v) for v in scene["box"]],
            [float(v) for v in data["box"]],
            fail,
            beyond_ok="this model reads relative geometry only" if relative else finetune,
            why=(
                f"this model ({hp['encoding']} encoding, {hp.get('decoder_mode')} decoder, "
                f"{data['boundary']}) depends on the box (volume fraction, drive wavelength); "
                "only exact-frame grip models of a sheared scene are applied in any box"
            ),
        )
    )
    encoder = dict(hp.get("encoder") or {})
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
