"""Shareable model files: weights and hyperparameters as data only, nothing to unpickle.

A gripdem model file is ONE ``.safetensors`` file (https://github.com/huggingface/safetensors:
an 8-byte header length, a JSON header, raw tensor bytes; reading it runs no code). Its
header's ``__metadata__`` (string to string) holds:

    format           "gripdem-model"
    format_version   "1"
    hparams          JSON: the keyword arguments of TrajectoryModule (plain values only)
    card             JSON: a free-form model card (training data, split, metrics, version)
    gripdem_version  the version that wrote the file
    tensors_sha256   SHA-256 of the tensors (names, dtypes, shapes, bytes): a flipped bit is
                     refused, not loaded as other weights

and its tensors are the model's ``state_dict``. :func:`save_model_file` writes it atomically
(temporary file, then rename); :func:`load_model_file` reads it back and checks it against the
model its hyperparameters build. Every refusal is a :class:`CheckpointError` naming the file,
the field and what was found and expected.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import math
import os
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gripdem._version import __version__
from gripdem.data.h5io import atomic_path
from gripdem.errors import CheckpointError

FORMAT = "gripdem-model"
FORMAT_VERSION = 1
#: the hyperparameters every gripdem model has (the rest take TrajectoryModule's defaults)
REQUIRED_HPARAMS = ("scene", "normalizer", "encoding", "horizon")
#: a safetensors JSON header larger than this is refused before it is read (the library's own
#: limit is 100 MB)
MAX_HEADER_BYTES = 100 << 20


def plain(value: Any, where: str = "hparams") -> Any:
    """``value`` as JSON-able plain values (dicts with string keys, lists, str, int, float,
    bool, None); numpy scalars and arrays become numbers and lists. Raises TypeError naming
    the entry that is not plain data (a tensor, an object)."""
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Mapping):
        out = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise TypeError(f"{where}: key {key!r} is not a string")
            out[key] = plain(item, f"{where}.{key}")
        return out
    if isinstance(value, (list, tuple)):
        return [plain(item, f"{where}[{i}]") for i, item in enumerate(value)]
    raise TypeError(f"{where}: {type(value).__name__} is not plain data")


def save_model_file(
    model: Any,
    path: str | os.PathLike,
    card: Mapping[str, Any] | None = None,
    state_dict: Mapping[str, torch.Tensor] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write ``model`` (a TrajectoryModule, or its hyperparameters as a mapping together with
    ``state_dict``) and ``card`` as one ``.safetensors`` file, atomically."""
    path = Path(path)
    if isinstance(model, Mapping):
        hparams = dict(model)
        if state_dict is None:
            raise ValueError("save_model_file: hyperparameters given without a state_dict")
    else:
        hparams = dict(model.hparams)
        state_dict = model.state_dict() if state_dict is None else state_dict
    # clone: safetensors refuses tensors that share memory; contiguous CPU copies of each
    tensors = {name: t.detach().to("cpu").contiguous().clone() for name, t in state_dict.items()}
    try:
        metadata = {
            "format": FORMAT,
            "format_version": str(FORMAT_VERSION),
            "hparams": json.dumps(plain(hparams, "hparams"), sort_keys=True),
            "card": json.dumps(plain(dict(card or {}), "card"), sort_keys=True),
            "gripdem_version": __version__,
            "tensors_sha256": tensors_digest(tensors),
        }
    except TypeError as exc:
        raise CheckpointError(path, "hparams", f"expected plain values only ({exc})") from None
    from safetensors.torch import save

    with atomic_path(path, overwrite) as tmp:
        tmp.write_bytes(save(tensors, metadata=metadata))  # permissions as any file written here
    return path


def is_safetensors(path: str | os.PathLike) -> bool:
    """Does the file start like a safetensors file (header length, then ``{``)?"""
    try:
        with open(path, "rb") as fh:
            head = fh.read(9)
    except OSError:
        return False
    return len(head) == 9 and head[8:9] == b"{"


def _header(path: Path) -> dict[str, Any]:
    """The JSON header, read by hand with its size checked first (no library code yet)."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        raw = fh.read(8)
        if len(raw) < 8:
            raise CheckpointError(path, "<file>", f"expected a safetensors file, got {size} bytes")
        (length,) = struct.unpack("<Q", raw)
        if length > min(MAX_HEADER_BYTES, size - 8):
            raise CheckpointError(
                path,
                "<header>",
                f"declares a {length}-byte header in a {size}-byte file (at most "
                f"{min(MAX_HEADER_BYTES, size - 8)}): truncated or not a safetensors file",
            )
        text = fh.read(length)
    try:
        header = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        raise CheckpointError(path, "<header>", "expected a UTF-8 JSON header") from None
    if not isinstance(header, dict):
        raise CheckpointError(path, "<header>", "expected a JSON object")
    return header


def _json_field(path: Path, metadata: Mapping[str, Any], name: str) -> dict[str, Any]:
    text = metadata.get(name)
    if not isinstance(text, str):
        raise CheckpointError(path, name, f"missing from the file's metadata ({sorted(metadata)})")
    try:
        value = json.loads(text)
    except (json.JSONDecodeError, RecursionError):
        raise CheckpointError(path, name, f"expected a JSON object, got {text[:60]!r}") from None
    if not isinstance(value, dict):
        raise CheckpointError(path, name, f"expected a JSON object, got {type(value).__name__}")
    return value


def check_hparams(path: str | os.PathLike, hparams: Any) -> dict[str, Any]:
    """The hyperparameters as a dict with every required key (else CheckpointError)."""
    if not isinstance(hparams, Mapping):
        raise CheckpointError(path, "hparams", f"expected a mapping, got {type(hparams).__name__}")
    missing = [k for k in REQUIRED_HPARAMS if k not in hparams]
    if missing:
        raise CheckpointError(
            path,
            "hparams",
            f"not a gripdem model: the hyperparameters lack {missing} (found "
            f"{sorted(map(str, hparams))[:8]}); use checkpoints/best.ckpt or "
            "checkpoints/best.safetensors of a `python -m gripdem.run` output directory",
        )
    _check_scene(path, hparams["scene"])
    return dict(hparams)


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def _check_scene(path: str | os.PathLike, scene: Any) -> None:
    """The trained scene's values are what they claim (compared with data as numbers)."""
    if not isinstance(scene, Mapping):
        raise CheckpointError(path, "hparams.scene", f"expected a mapping, got {scene!r:.80}")
    box = scene.get("box")
    if not (
        isinstance(box, (list, tuple))
        and len(box) == 3
        and all((_number(v) or 0.0) > 0 for v in box)
    ):
        raise CheckpointError(
            path, "hparams.scene.box", f"expected 3 positive lengths, got {box!r:.80}"
        )
    if scene.get("boundary") not in ("periodic", "lees_edwards"):
        raise CheckpointError(
            path,
            "hparams.scene.boundary",
            f"expected periodic or lees_edwards, got {scene.get('boundary')!r:.80}",
        )
    needed = ["diameter", "frame_interval"]
    if scene["boundary"] == "lees_edwards":
        needed += ["shear_rate", "le_sign", "le_time_origin"]
    for key in needed:
        value = _number(scene.get(key))
        if value is None or (key in ("diameter", "frame_interval") and value <= 0):
            raise CheckpointError(
                path,
                f"hparams.scene.{key}",
                f"expected a finite number, got {scene.get(key)!r:.80}",
            )
    if _number(scene.get("body_force_amplitude", 0.0)) is None:
        raise CheckpointError(
            path, "hparams.scene.body_force_amplitude", "expected a finite number"
        )


def read_model_file(
    path: str | os.PathLike, tensors: bool = True
) -> tuple[dict[str, Any], dict[str, torch.Tensor], dict[str, Any]]:
    """``(hparams, state_dict, card)`` of a model file, format-checked (``tensors=False``:
    an empty state dict, the header only)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such model file")
    metadata = _header(path).get("__metadata__")
    if not isinstance(metadata, dict):
        raise CheckpointError(path, "__metadata__", "missing: not a gripdem model file")
    if metadata.get("format") != FORMAT:
        raise CheckpointError(
            path, "format", f"expected {FORMAT!r}, got {metadata.get('format')!r}"
        )
    if metadata.get("format_version") != str(FORMAT_VERSION):
        raise CheckpointError(
            path,
            "format_version",
            f"expected {FORMAT_VERSION}, got {metadata.get('format_version')!r} (a newer "
            "gripdem wrote it?)",
        )
    hparams = check_hparams(path, _json_field(path, metadata, "hparams"))
    card = _json_field(path, metadata, "card")
    state: dict[str, torch.Tensor] = {}
    if tensors:
        from safetensors import safe_open

        try:
            with safe_open(str(path), framework="pt", device="cpu") as fh:
                state = {name: fh.get_tensor(name) for name in fh.keys()}  # noqa: SIM118
        except Exception as exc:  # safetensors' own error type, OSError, ValueError
            raise CheckpointError(
                path, "<tensors>", f"unreadable ({type(exc).__name__}: {exc})"
            ) from None
        if metadata.get("tensors_sha256") != tensors_digest(state):
            raise CheckpointError(
                path,
                "tensors_sha256",
                "the weights do not match the checksum written with them: a corrupted or "
                "altered file",
            )
    return hparams, state, card


def tensors_digest(tensors: Mapping[str, torch.Tensor]) -> str:
    """SHA-256 over the tensors (names, dtypes, shapes and bytes, in name order)."""
    digest = hashlib.sha256()
    for name in sorted(tensors):
        tensor = tensors[name].detach().to("cpu").contiguous().reshape(-1)
        digest.update(f"{name}|{tensor.dtype}|{tuple(tensor.shape)}|".encode())
        digest.update(tensor.view(torch.uint8).numpy().tobytes() if tensor.numel() else b"")
    return digest.hexdigest()


def check_state(
    path: str | os.PathLike, state: Mapping[str, torch.Tensor], expected: Mapping[str, Any]
) -> None:
    """Tensor names and shapes of ``state`` exactly those of ``expected`` (a model's
    ``state_dict``), else a CheckpointError naming the first difference."""
    missing = sorted(set(expected) - set(state))
    extra = sorted(set(state) - set(expected))
    if missing or extra:
        raise CheckpointError(
            path,
            "state_dict",
            f"tensors do not match the model its hparams build: missing {missing[:4]}"
            f"{'...' if len(missing) > 4 else ''}, unexpected {extra[:4]}"
            f"{'...' if len(extra) > 4 else ''}",
        )
    for name, want in expected.items():
        got = state[name]
        if not isinstance(got, torch.Tensor):
            raise CheckpointError(path, f"state_dict.{name}", "expected a tensor")
        if tuple(got.shape) != tuple(want.shape):
            raise CheckpointError(
                path,
                f"state_dict.{name}",
                f"shape {tuple(got.shape)} in the file, {tuple(want.shape)} in the model its "
                "hparams build",
            )
        if got.is_floating_point() and not bool(torch.isfinite(got).all()):
            raise CheckpointError(
                path, f"state_dict.{name}", "expected finite weights, found NaN/Inf"
            )


def build_module(
    path: str | os.PathLike,
    hparams: Mapping[str, Any],
    state: Mapping[str, torch.Tensor],
    scene: Mapping[str, Any] | None = None,
):
    """``TrajectoryModule(**hparams)`` (``scene`` replacing the trained one) with ``state``
    loaded strictly, in eval mode. The model is first built on the meta device (no memory):
    hyperparameters that build something else than the file's tensors (or a model far larger
    than the file) are refused before any allocation."""
    from gripdem.models.module import TrajectoryModule

    hp = dict(hparams)
    if scene is not None:
        hp["scene"] = dict(scene)
    accepted = inspect.signature(TrajectoryModule.__init__).parameters
    kwargs = {k: v for k, v in hp.items() if k in accepted and k != "self"}
    try:
        with torch.device("meta"):
            shapes = TrajectoryModule(**kwargs).state_dict()
    except Exception as exc:  # any failure to build from a file's values is bad input
        raise CheckpointError(
            path, "hparams", f"do not build a gripdem model ({type(exc).__name__}: {exc})"
        ) from None
    check_state(path, state, shapes)
    model = TrajectoryModule(**kwargs)
    model.load_state_dict(dict(state), strict=True)
    return model.eval()


def load_model_file(
    path: str | os.PathLike,
) -> tuple[dict[str, Any], dict[str, torch.Tensor], dict[str, Any]]:
    """``(hparams, state_dict, card)`` of a model file, checked against the model its
    hyperparameters build (names and shapes). Raises :class:`CheckpointError`."""
    hparams, state, card = read_model_file(path)
    build_module(path, hparams, state)
    return hparams, state, card


def finite_metrics(metrics: Mapping[str, Any]) -> dict[str, float]:
    """The finite numeric entries of ``metrics`` (for a model card)."""
    out = {}
    for key, value in metrics.items():
        if isinstance(value, (int, float, np.generic)) and not isinstance(value, bool):
            number = float(value)
            if math.isfinite(number):
                out[str(key)] = number
    return out
