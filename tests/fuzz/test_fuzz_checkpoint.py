"""Fuzzing the checkpoint loader (Lightning ``.ckpt`` and ``.safetensors`` model files):
corrupted, crafted and absurd files are refused with a CheckpointError naming the file, or
load into a model; never another exception, code run from the file, a hang or a memory
blow-up."""

from __future__ import annotations

import json
import struct
import tempfile
from pathlib import Path

import pytest
from checkpoints import untrained_checkpoint
from crafted import crafted_checkpoint, payloads, pickle_bytes, rewrite_member
from fuzzing import FUZZ, refuses_or_accepts
from hypothesis import given, settings
from hypothesis import strategies as st
from safetensors.torch import save_file

from gripdem.data.dataset_io import write_dataset
from gripdem.inference.checkpoint import load_checkpoint_model, read_checkpoint
from gripdem.inference.model_file import CheckpointError, save_model_file, tensors_digest

ERRORS = (CheckpointError,)


@pytest.fixture(scope="module")
def base(tmp_path_factory, trajectories) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("fuzz_ckpt")
    data = write_dataset(root / "le.h5", trajectories(n_sims=3, n_frames=30, n_particles=16))
    ckpt = untrained_checkpoint(data, root / "best.ckpt", ["scene=lebc"])
    hparams, state, _ = read_checkpoint(ckpt)
    model = save_model_file(hparams, root / "best.safetensors", {"source": "fuzz"}, state)
    return {"ckpt": ckpt, "safetensors": model}


def metadata_of(path: Path) -> dict[str, str]:
    """The ``__metadata__`` of a safetensors file (its JSON header, read by hand)."""
    raw = path.read_bytes()
    (length,) = struct.unpack("<Q", raw[:8])
    return json.loads(raw[8 : 8 + length])["__metadata__"]


def load(path: Path, target: str, marker: Path | None = None) -> None:
    model, _ = refuses_or_accepts(target, lambda: load_checkpoint_model(path), ERRORS, path)
    if model is not None:
        assert not model.training  # a model came out, in eval mode
    if marker is not None:
        assert not marker.exists(), "code from the file ran"


@settings(FUZZ, max_examples=100)
@given(kind=st.sampled_from(["ckpt", "safetensors"]), data=st.data())
def test_truncated_and_bit_flipped_files(base, kind, data):
    raw = bytearray(base[kind].read_bytes())
    if data.draw(st.booleans(), "truncate"):
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    else:
        for _ in range(data.draw(st.integers(1, 16), "flips")):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"fuzzed.{kind}"
        path.write_bytes(bytes(raw))
        load(path, f"checkpoint bytes ({kind})")


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(10**6), 10**12) | st.floats() | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=12,
)


@settings(FUZZ, max_examples=120)
@given(data=st.data())
def test_model_file_metadata(base, data):
    """Hyperparameters and card replaced in part by arbitrary JSON, keys dropped, formats
    changed: the model those hyperparameters build must match the file's tensors."""
    hparams, state, _ = read_checkpoint(base["safetensors"])
    meta = {"format": "gripdem-model", "format_version": "1", "card": "{}"}
    meta["tensors_sha256"] = tensors_digest(state)
    path_in = data.draw(st.sampled_from(["scene", "normalizer", "encoder", "linear_ar", None]))
    edit = data.draw(st.sampled_from(["replace", "drop", "nested", "none"]))
    if edit == "none":
        pass
    elif path_in is None:
        hparams = data.draw(json_values)
    elif edit == "drop":
        hparams.pop(path_in, None)
    elif edit == "replace" or not isinstance(hparams.get(path_in), dict) or not hparams[path_in]:
        hparams[path_in] = data.draw(json_values)
    else:
        key = data.draw(st.sampled_from(sorted(hparams[path_in])))
        hparams[path_in][key] = data.draw(json_values)
    meta["hparams"] = json.dumps(hparams)
    key = data.draw(st.sampled_from(["card", "format", "format_version", "tensors_sha256", "x"]))
    meta[key] = data.draw(st.sampled_from(["{}", "[]", "2", "gripdem-model", "1", "{oops", ""]))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fuzzed.safetensors"
        save_file(state, str(path), metadata=meta)
        load(path, "model file metadata")


@settings(FUZZ, max_examples=60)
@given(
    name=st.sampled_from(sorted(payloads(Path("m")))),
    where=st.sampled_from(["hyper_parameters", "state_dict", "callbacks", "optimizer_states"]),
    garbage=st.one_of(st.none(), st.binary(max_size=64)),
)
def test_crafted_pickles_run_nothing(name, where, garbage):
    with tempfile.TemporaryDirectory() as tmp:
        marker = Path(tmp) / "pwned"
        path = crafted_checkpoint(Path(tmp) / "model.ckpt", payloads(marker)[name], where)
        if garbage is not None:  # random pickle opcodes after (or instead of) the payload
            stream = pickle_bytes(path)[: len(garbage)] + garbage
            path = rewrite_member(path, Path(tmp) / "garbage.ckpt", "data.pkl", stream)
        load(path, "crafted pickles", marker)


@settings(FUZZ, max_examples=30)
@given(
    numel=st.sampled_from([10**6, 10**9, 10**12, 2**62]),
    kind=st.sampled_from(["safetensors shape", "zip bomb", "header length"]),
)
def test_absurd_sizes(base, numel, kind):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "absurd.bin"
        if kind == "safetensors shape":  # a header promising a huge tensor in a tiny file
            header = {"w": {"dtype": "F32", "shape": [numel], "data_offsets": [0, 4 * numel]}}
            header["__metadata__"] = metadata_of(base["safetensors"])
            text = json.dumps(header).encode()
            path.write_bytes(struct.pack("<Q", len(text)) + text + b"\0" * 16)
        elif kind == "zip bomb":  # a compressed record that expands far beyond the file
            path = rewrite_member(
                base["ckpt"], path, "data.pkl", b"\0" * min(numel, 10**7), compress=True
            )
        else:
            path.write_bytes(struct.pack("<Q", numel) + b"{" + b"\0" * 64)
        load(path, "checkpoint absurd sizes")
