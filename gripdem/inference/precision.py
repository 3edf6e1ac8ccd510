"""Reduced precision for the surrogate's encoder: bf16 where the hardware computes it natively.

The contact encoder's per-edge products dominate a forward pass (``gripdem.nn.contact``).
CPUs with AVX-512 bf16 or AMX tiles (Intel Cooper Lake, Sapphire Rapids and later; AMD Zen 4
and later) and CUDA GPUs of compute capability 8.0+ compute them in bf16 at two or more times
the fp32 rate; elsewhere bf16 is emulated and slower, so ``auto`` keeps fp32 there.

Only the encoder is cast: its inputs are formed in fp32 (the gap transforms resolve overlaps of
1e-5 d) and its output is cast back, so the decoder, the AR prior, the decoding of positions
(float64) and everything after stay as they were.
"""

from __future__ import annotations

import copy
import functools
import warnings
from pathlib import Path

import torch

PRECISIONS = ("auto", "fp32", "bf16")
#: /proc/cpuinfo flags of native bf16 arithmetic
CPU_BF16_FLAGS = ("avx512_bf16", "amx_bf16")


@functools.lru_cache(maxsize=1)
def cpu_bf16_flags() -> tuple[str, ...]:
    """The native bf16 units this CPU reports (Linux /proc/cpuinfo; empty elsewhere)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return ()
    for line in text.splitlines():
        if line.startswith("flags"):
            flags = set(line.split(":", 1)[1].split())
            return tuple(f for f in CPU_BF16_FLAGS if f in flags)
    return ()


def bf16_supported(device: torch.device | str = "cpu") -> bool:
    """Whether ``device`` computes bf16 natively (a CUDA device of compute capability 8.0+, a
    CPU with AVX-512 bf16 or AMX)."""
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    return device.type == "cpu" and bool(cpu_bf16_flags())


def resolve_precision(precision: str, device: torch.device | str = "cpu") -> str:
    """``auto`` -> ``bf16`` where the device has bf16 units, else ``fp32``; ``bf16`` where it
    has none runs emulated (the same numbers, slower than fp32) with a warning."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    native = bf16_supported(device)
    if precision == "auto":
        return "bf16" if native else "fp32"
    if precision == "bf16" and not native:
        warnings.warn(
            f"precision bf16: {torch.device(device)} has no native bf16 units (CPU flags "
            f"{' or '.join(CPU_BF16_FLAGS)}, or a CUDA GPU of compute capability 8.0+): bf16 "
            "is emulated there, slower than fp32 (precision auto picks fp32)",
            stacklevel=2,
        )
    return precision


def set_encoder_precision(model, precision: str) -> str:
    """Cast ``model.encoder``'s weights for ``precision`` (auto | fp32 | bf16, see
    :func:`resolve_precision`) in place; returns the precision used. Other modules stay fp32."""
    device = next(model.parameters()).device
    used = resolve_precision(precision, device)
    model.encoder.to(torch.bfloat16 if used == "bf16" else torch.float32)
    return used


def with_encoder_precision(model, precision: str):
    """``model`` itself for fp32; for bf16 a shallow copy of it that holds a bf16 copy of the
    encoder and shares every other module, parameter and attribute (the model passed in is
    left as it was; a deep copy of the whole module costs ~10 ms, a rollout's set-up)."""
    if precision == "fp32":
        return model
    clone = copy.copy(model)
    clone._modules = dict(model._modules)  # nn.Module keeps its children here
    clone._modules["encoder"] = copy.deepcopy(model.encoder)
    set_encoder_precision(clone, precision)
    return clone
