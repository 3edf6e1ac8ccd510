"""A diverging run stops with a clear error naming the step; the last good checkpoint stays."""

import lightning as L
import pytest
import torch
from lightning.pytorch.callbacks import Callback, ModelCheckpoint

from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.models.module import TrajectoryModule


class PoisonInSecondEpoch(Callback):
    """Makes the weights non-finite at the first step of the second epoch, as a divergence
    inside an epoch would (after the first epoch's checkpoint was written)."""

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        if trainer.current_epoch == 1:
            with torch.no_grad():
                pl_module.decoder.heads[0].head.bias.fill_(float("nan"))


def test_nan_loss_stops_training_and_keeps_the_last_good_checkpoint(tmp_path, tiny_pbc_path):
    dm = TrajectoryDataModule(
        tiny_pbc_path, split="6-3", history_len=3, graph_cutoff=1.5, encoding="sincos"
    )
    dm.setup("fit")
    meta = dm.meta
    scene = {
        k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in meta.boundary.to_attrs().items()
    }
    model = TrajectoryModule(
        scene={**scene, "diameter": meta.diameter},
        normalizer=dm.normalizer.to_dict(),
        encoding="sincos",
        horizon=3,
        encoder={"channels": 4, "n_blocks": 1},
        hidden=8,
    )
    checkpoint = ModelCheckpoint(dirpath=tmp_path, monitor="val/rmse", save_last=True)
    trainer = L.Trainer(
        max_epochs=3,
        limit_train_batches=2,
        limit_val_batches=1,
        callbacks=[checkpoint, PoisonInSecondEpoch()],
        logger=False,
        enable_progress_bar=False,
    )
    with pytest.raises(FloatingPointError, match=r"non-finite training loss .* global step 2"):
        trainer.fit(model, dm)
    last = torch.load(tmp_path / "last.ckpt", weights_only=True)
    assert last["epoch"] == 0
    bad = [
        k for k, v in last["state_dict"].items() if v.is_floating_point() and not v.isfinite().all()
    ]
    assert bad == [], (bad, last["global_step"])
