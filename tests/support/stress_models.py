"""Models and configurations for the stress suite (``tests/stress``): smoke models built by
:mod:`gripdem.runner.experiment` from the configs, perturbed copies (every weight moved by
seeded noise, so every layer matters), their decoded test-window predictions, and generator
configurations of the tiny preset."""

from __future__ import annotations

from pathlib import Path

import torch
import yaml
from hydra import compose, initialize_config_dir

from gripdem.boundary import Box
from gripdem.data.batch import collate_windows
from gripdem.dem.config import GeneratorConfig
from gripdem.evaluation.metrics import position_residuals, rmse
from gripdem.run import CONFIG_DIR
from gripdem.runner.experiment import build_datamodule, build_model

ROOT = Path(__file__).resolve().parents[2]
CONF = ROOT / "conf"
D = 2.5e-6
DT = 5e-6


# --------------------------------------------------------------------------------------------
# helpers: models from the configs, their test-window predictions
# --------------------------------------------------------------------------------------------
def smoke_model(path: Path, *overrides: str):
    """(model, datamodule) of the smoke preset on ``path``, untrained."""
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("config", overrides=["experiment=smoke", f"data.path={path}", *overrides])
    dm = build_datamodule(cfg, Path(path))
    torch.manual_seed(0)
    return build_model(cfg, dm).eval(), dm


def perturb(model, scale: float = 0.05, seed: int = 1):
    """Move every weight by seeded noise of ``scale`` (zero-initialised heads included)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(scale * torch.randn(p.shape, generator=g, dtype=p.dtype))
    return model


@torch.no_grad()
def predict_windows(model, dm, part: str = "test", autocast: bool = False):
    """Decoded predictions, truths, target offsets (all windows of ``part``) and batches."""
    preds, trues, offs, batches = [], [], [], []
    for i in range(len(dm.datasets[part])):
        batch = collate_windows([dm.datasets[part][i]])
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
            out = model(batch)
        preds.append(model.decode(out, batch))
        trues.append(batch.target_positions.double().transpose(1, 2))
        offs.append(batch.target_offsets.double())
        batches.append(batch)
    return torch.cat(preds), torch.cat(trues), torch.cat(offs), batches


def rmse_over_d(pred, true, offsets, model) -> float:
    off = offsets if model.boundary.is_lees_edwards else None
    return rmse(position_residuals(pred, true, model.boundary.box, off)) / model.diameter


def inside(positions, box: Box) -> bool:
    half = torch.as_tensor(0.5 * box.lengths)
    return bool(((positions >= -half) & (positions < half)).all())


def generator_config(scene: str, **overrides) -> GeneratorConfig:
    s = yaml.safe_load((CONF / "scene" / f"{scene}.yaml").read_text())
    p = yaml.safe_load((CONF / "preset" / "tiny.yaml").read_text())
    for key, value in overrides.items():
        (p if key in p else s)[key] = value
    return GeneratorConfig.from_mappings(s, p, sims=1)


def collate_all(batches):
    """The windows of several one-window batches as one batch (for the baselines)."""
    from dataclasses import fields, replace

    first = batches[0]
    stacked = {}
    for f in fields(first):
        value = getattr(first, f.name)
        if isinstance(value, torch.Tensor) and not f.name.startswith("edge"):
            stacked[f.name] = torch.cat([getattr(b, f.name) for b in batches])
    return replace(first, **stacked)
