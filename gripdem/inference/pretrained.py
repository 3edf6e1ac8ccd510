"""Models that ship with gripdem: ``pretrained:NAME`` wherever a checkpoint path is accepted.

The default model of each built-in scene, trained by ``python -m gripdem.run`` on that scene's
default dataset, is stored in ``gripdem/inference/pretrained/NAME.safetensors``: a data-only model
file (:mod:`gripdem.inference.model_file`) whose card records the training data and the
configuration of the generator that made it, the split (and which simulations trained, validated
and tested the model: predict's in-sample check reads them), the out-of-sample metrics and the
gripdem version; ``NAME.md`` beside it is the same card for people. ``python -m gripdem.predict
pretrained:pbc DATA.h5`` applies one; ``model.init_from=pretrained:pbc`` fine-tunes from it.
"""

from __future__ import annotations

import os
from pathlib import Path

PREFIX = "pretrained:"
FOLDER = Path(__file__).resolve().parent / "pretrained"


def available() -> list[str]:
    """Names of the shipped models."""
    return sorted(p.stem for p in FOLDER.glob("*.safetensors"))


def is_pretrained(spec: str | os.PathLike) -> bool:
    return str(spec).startswith(PREFIX)


def resolve(spec: str | os.PathLike) -> Path:
    """``pretrained:NAME`` -> the shipped model file; any other value as a path."""
    if not is_pretrained(spec):
        return Path(spec)
    name = str(spec)[len(PREFIX) :]
    path = FOLDER / f"{name}.safetensors"
    if not path.is_file():
        raise FileNotFoundError(
            f"{spec}: no such shipped model; available: "
            + (", ".join(f"{PREFIX}{n}" for n in available()) or "none")
        )
    return path
