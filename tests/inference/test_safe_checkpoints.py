"""Loading checkpoints safely (issue 20): a Lightning ``.ckpt`` and its ``.safetensors`` model
file predict the same; a crafted checkpoint is refused and runs nothing; corrupted files get a
CheckpointError naming the file and the field."""

from __future__ import annotations

import contextlib
import io
import json
import math
import pickle
import re
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from crafted import (
    crafted_checkpoint,
    payloads,
    perturbed_checkpoint,
    pickle_bytes,
    rewrite_member,
)
from safetensors.torch import save_file

from gripdem.inference.checkpoint import (
    export_run_model,
    load_checkpoint_model,
    read_checkpoint,
)
from gripdem.inference.model_file import (
    CheckpointError,
    load_model_file,
    save_model_file,
    tensors_digest,
)
from gripdem.predict import main as predict

ROOT = Path(__file__).resolve().parents[2]


def run_predict(checkpoint, data, out) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        status = predict([str(checkpoint), str(data), "--out", str(out), "--no-overlap"])
    return status, err.getvalue()


def _arrays(path: Path) -> dict[str, np.ndarray]:
    found: dict[str, np.ndarray] = {}
    with h5py.File(path) as h5:
        h5.visititems(
            lambda k, v: found.update({k: v[()]}) if isinstance(v, h5py.Dataset) else None
        )
    return found


@pytest.fixture(scope="module")
def moved(tmp_path_factory, le_checkpoint) -> tuple[Path, Path]:
    """A .ckpt whose weights are off the constant-velocity start, and its model file."""
    root = tmp_path_factory.mktemp("moved")
    ckpt = perturbed_checkpoint(le_checkpoint, root / "checkpoints" / "moved.ckpt", seed=3)
    hparams, state, _ = read_checkpoint(ckpt)
    model_file = save_model_file(hparams, root / "moved.safetensors", {"note": "t"}, state)
    return ckpt, model_file


def test_ckpt_and_model_file_predict_the_same(tmp_path, le_file, moved):
    ckpt, model_file = moved
    outputs = {}
    for name, path in (("ckpt", ckpt), ("safetensors", model_file)):
        status, err = run_predict(path, le_file, tmp_path / f"{name}.h5")
        assert status == 0, err
        outputs[name] = _arrays(tmp_path / f"{name}.h5")
    a, b = outputs["ckpt"], outputs["safetensors"]
    assert sorted(a) == sorted(b)
    for key in a:
        if key.startswith("baseline/"):
            # recomputed in float64 by each run: torch's vectorised sin/cos (the mean-flow
            # profile) can differ in the last bit with the arrays' memory alignment (measured
            # 2e-14 relative in 1 of 4 runs)
            np.testing.assert_allclose(a[key], b[key], rtol=1e-12, atol=0, err_msg=key)
        else:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    cv = a["baseline/constant_velocity"]
    assert np.abs(a["pred_positions"] - cv).max() > 0  # the moved weights do matter


def test_model_file_round_trip_and_run_export(tmp_path, moved):
    ckpt, _ = moved
    model = load_checkpoint_model(ckpt)
    run = {"scene": "lebc", "split": "10-5", "model": "contact", "seed": 0}
    path = export_run_model(
        model, tmp_path / "best.safetensors", run, {"test/rmse": 1.5e-9, "x": math.nan}
    )
    hparams, state, card = load_model_file(path)
    assert hparams == json.loads(json.dumps(dict(model.hparams)))
    assert all(torch.equal(state[k], v) for k, v in model.state_dict().items())
    assert (card["scene"], card["split"], card["model"]) == ("lebc", "10-5", "contact")
    assert card["metrics"] == {"test/rmse": 1.5e-9} and card["gripdem_version"]
    assert [p.name for p in tmp_path.iterdir()] == ["best.safetensors"]  # atomic: no temp left


def test_a_model_file_from_before_the_encoder_rename_predicts_the_same(tmp_path, le_file, moved):
    """``interaction``, the contact encoder's name before gripdem 0.1, in a file's
    hyperparameters: the file loads and predicts what it predicted before."""
    _, model_file = moved
    hparams, state, card = load_model_file(model_file)
    assert hparams["encoder"]["name"] == "contact"
    hparams["encoder"]["name"] = "interaction"
    old_file = save_model_file(hparams, tmp_path / "old.safetensors", card, state)
    assert load_model_file(old_file)[0]["encoder"]["name"] == "interaction"  # read as written
    outputs = []
    for path in (model_file, old_file):
        status, err = run_predict(path, le_file, tmp_path / f"{path.stem}.h5")
        assert status == 0 and "deprecated" not in err, err
        outputs.append(_arrays(tmp_path / f"{path.stem}.h5")["pred_positions"])
    np.testing.assert_array_equal(outputs[0], outputs[1])


@pytest.mark.parametrize("name", sorted(payloads(Path("m"))))
@pytest.mark.parametrize("where", ["hyper_parameters", "state_dict", "callbacks"])
def test_a_crafted_checkpoint_is_refused_and_runs_nothing(tmp_path, le_file, name, where):
    marker = tmp_path / "pwned"
    bad = crafted_checkpoint(tmp_path / "model.ckpt", payloads(marker)[name], where)
    with pytest.raises(CheckpointError, match=r"model\.ckpt: field '<pickle>': refused"):
        read_checkpoint(bad)
    status, err = run_predict(bad, le_file, tmp_path / "p.h5")
    assert status == 1 and err.count("\n") == 1 and err.startswith("error: ")
    assert "nothing in it was run" in err
    assert not marker.exists() and not (tmp_path / "p.h5").exists()


def test_the_payload_is_live(tmp_path):
    """The refusal above is meaningful: plain unpickling of the same bytes runs the payload."""
    marker = tmp_path / "pwned"
    payload = payloads(marker)["pathlib.write_text"]
    bad = crafted_checkpoint(tmp_path / "model.ckpt", payload, where="state_dict")  # no tensor
    pickle.loads(pickle_bytes(bad))  # the unsafe way, deliberately, in a folder of its own
    assert marker.read_text() == "pwned"


def _safetensors(path, tensors, metadata):
    save_file(tensors, str(path), metadata=metadata)
    return path


def bad_files(tmp: Path, ckpt: Path, model_file: Path) -> dict[str, tuple[Path, str]]:
    """name -> (file, expected field) of corrupted checkpoints and model files."""
    hparams, state, _ = read_checkpoint(ckpt)
    raw_ckpt, raw_model = ckpt.read_bytes(), model_file.read_bytes()
    meta = {"format": "gripdem-model", "format_version": "1", "card": "{}"}
    shrunk = dict(state)
    name = next(k for k, v in state.items() if v.ndim == 2)
    shrunk[name] = state[name][:-1].contiguous()
    cases = {
        "truncated ckpt": (raw_ckpt[: len(raw_ckpt) // 2], "<file>"),
        "truncated safetensors": (raw_model[: len(raw_model) - 100], "<tensors>"),
        "empty file": (b"", "<file>"),
        "random bytes": (bytes(range(256)) * 8, "<file>"),
        "legacy pickle": (pickle.dumps({"state_dict": {}}), "<file>"),
        "absurd header length": ((2**62).to_bytes(8, "little") + b"{}", "<header>"),
        "header not JSON": (len(b"{oops").to_bytes(8, "little") + b"{oops", "<header>"),
    }
    out = {}
    for label, (data, field) in cases.items():
        path = tmp / (re.sub(r"\W", "_", label) + (".ckpt" if "ckpt" in label else ".bin"))
        path.write_bytes(data)
        out[label] = (path, field)
    out["no metadata"] = (_safetensors(tmp / "a.safetensors", state, None), "__metadata__")
    out["hparams missing keys"] = (
        _safetensors(tmp / "b.safetensors", state, {**meta, "hparams": '{"encoding": "x"}'}),
        "hparams",
    )
    out["tensor shape mismatch"] = (
        _safetensors(
            tmp / "c.safetensors",
            shrunk,
            {**meta, "hparams": json.dumps(hparams), "tensors_sha256": tensors_digest(shrunk)},
        ),
        f"state_dict.{name}",
    )
    extra = {**state, "evil": torch.zeros(3)}
    out["extra tensor"] = (
        _safetensors(
            tmp / "d.safetensors",
            extra,
            {**meta, "hparams": json.dumps(hparams), "tensors_sha256": tensors_digest(extra)},
        ),
        "state_dict",
    )
    flipped = bytearray(raw_model)
    flipped[-3] ^= 0x10  # one bit of the last weight
    out["flipped weight bit"] = (tmp / "flipped.safetensors", "tensors_sha256")
    out["flipped weight bit"][0].write_bytes(bytes(flipped))
    out["compressed zip member"] = (
        rewrite_member(ckpt, tmp / "z.ckpt", "data.pkl", pickle_bytes(ckpt), compress=True),
        "data.pkl",
    )
    out["HDF5 file"] = (None, "<file>")
    return out


def test_corrupted_files_are_refused_with_the_field(tmp_path, le_file, moved):
    ckpt, model_file = moved
    for label, (path, field) in bad_files(tmp_path, ckpt, model_file).items():
        path = le_file if path is None else path
        with pytest.raises(CheckpointError) as info:
            load_checkpoint_model(path)
        message = str(info.value)
        assert message.startswith(f"{path}: field '") and info.value.field.endswith(field), (
            label,
            message,
        )
        status, err = run_predict(path, le_file, tmp_path / "p.h5")
        assert status == 1 and err.count("\n") == 1 and str(path) in err, (label, err)


def test_no_unsafe_loading_anywhere_in_gripdem():
    """Every checkpoint gripdem reads goes through the safe loader (``weights_only=False``
    only where a checkpoint is saved whole: Lightning's ``save_checkpoint``)."""
    for source in (ROOT / "gripdem").rglob("*.py"):
        text = source.read_text()
        for line in text.splitlines():
            if "weights_only=False" in line:
                assert "save_checkpoint(" in line, f"{source}: {line.strip()}"
        assert "load_from_checkpoint" not in text, source
        assert not re.search(r"\bpickle\.loads?\(", text), source


def test_zip_members_are_as_torch_save_writes_them(moved):
    with zipfile.ZipFile(moved[0]) as archive:
        assert {i.compress_type for i in archive.infolist()} == {zipfile.ZIP_STORED}
