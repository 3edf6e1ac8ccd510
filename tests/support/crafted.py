"""Checkpoint files for the safe-loading tests: real Lightning checkpoints with weights moved
off their (constant-velocity) start, and crafted files: pickled payloads that would run code
if unpickled, as an attacker would share them.

Nothing here unpickles anything; a payload runs only where a test deliberately shows that it
is live (plain ``pickle.loads`` of its bytes, in a folder of its own).
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import zipfile
from pathlib import Path

import torch


def perturbed_checkpoint(source: Path, target: Path, seed: int = 0, scale: float = 0.05) -> Path:
    """``source`` (a Lightning checkpoint) with every floating-point weight moved by seeded
    noise, saved as a Lightning checkpoint again (same keys, same zip format)."""
    content = torch.load(source, map_location="cpu", weights_only=True)
    generator = torch.Generator().manual_seed(seed)
    state = content["state_dict"]
    for name, tensor in state.items():
        if tensor.is_floating_point() and name != "change_std":
            noise = torch.randn(tensor.shape, generator=generator, dtype=torch.float64)
            state[name] = tensor + (scale * noise).to(tensor.dtype)
    target.parent.mkdir(parents=True, exist_ok=True)
    torch.save(content, target)
    return target


class Payload:
    """Pickles as a call of ``function(*args)``: what a crafted checkpoint carries."""

    def __init__(self, function, *args):
        self.function, self.args = function, args

    def __reduce__(self):
        return self.function, self.args


def payloads(marker: Path) -> dict[str, Payload]:
    """Payloads that each create ``marker`` when unpickled (different ways in)."""
    return {
        "os.system": Payload(os.system, f"touch {marker}"),
        "subprocess.call": Payload(subprocess.call, ["touch", str(marker)]),
        "pathlib.write_text": Payload(pathlib.Path.write_text, marker, "pwned"),
        "builtins.exec": Payload(exec, f"open({str(marker)!r}, 'w').write('pwned')"),
        "builtins.eval": Payload(eval, f"open({str(marker)!r}, 'w').write('pwned')"),
    }


def crafted_checkpoint(path: Path, payload: Payload, where: str = "hyper_parameters") -> Path:
    """A zip checkpoint as torch.save writes it, with ``payload`` at ``where`` (the rest a
    plausible Lightning layout)."""
    content = {"state_dict": {"w": torch.zeros(2)}, "hyper_parameters": {"scene": {}}}
    content[where] = payload
    torch.save(content, path)
    return path


def pickle_bytes(path: Path) -> bytes:
    """The pickle stream (``data.pkl``) of a torch zip checkpoint."""
    with zipfile.ZipFile(path) as archive:
        name = next(n for n in archive.namelist() if n.endswith("data.pkl"))
        return archive.read(name)


def rewrite_member(path: Path, target: Path, name_end: str, data: bytes, compress=False) -> Path:
    """``path`` with the zip member ending in ``name_end`` replaced by ``data``."""
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(target, "w") as dst:
        for info in src.infolist():
            body = data if info.filename.endswith(name_end) else src.read(info)
            kind = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
            dst.writestr(info.filename, body, compress_type=kind)
    return target
