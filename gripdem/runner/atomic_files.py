"""Lightning's files of a run written atomically: checkpoints and TensorBoard's hparams.yaml.

Lightning (2.6) saves a checkpoint through an fsspec transaction: a temporary file in the
system's temporary folder (``$TMPDIR``, ``/tmp``), then ``shutil.move`` onto the target. That is
a rename only when both lie on one file system; otherwise (``/tmp`` on tmpfs, outputs on disk
or a network file system) it is a copy into the target's final name, which a kill can cut
short, and a killed save leaves its temporary file in ``/tmp``. TensorBoardLogger writes
``hparams.yaml`` in place, once. Here both go through :func:`gripdem.data.h5io.atomic_path`
(a temporary file next to the target, renamed over it when complete), the one place where
gripdem's files are made atomic.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from lightning.fabric.plugins.io.torch_io import TorchCheckpointIO
from lightning.pytorch.core.saving import save_hparams_to_yaml
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_only

from gripdem.data.h5io import atomic_path, temporaries_of

__all__ = ["AtomicCheckpointIO", "AtomicTensorBoardLogger"]


def _local(path: Any) -> bool:
    return "://" not in str(path)


class AtomicCheckpointIO(TorchCheckpointIO):
    """``torch.save`` into a temporary file next to the checkpoint, then ``os.replace``: a
    kill at any moment leaves the previous complete checkpoint (or none), never a torn one;
    the temporary files of saves killed by SIGKILL go at the next save of the same name.
    Remote paths (``s3://`` ...) keep Lightning's own saving."""

    def save_checkpoint(
        self, checkpoint: dict[str, Any], path: Any, storage_options: Any | None = None
    ) -> None:
        if storage_options is not None or not _local(path):
            super().save_checkpoint(checkpoint, path, storage_options)
            return
        with atomic_path(path, overwrite=True) as tmp:
            torch.save(checkpoint, tmp)
        path = Path(path)
        for stale in temporaries_of(path.parent, path.stem):  # a save killed by SIGKILL
            stale.unlink(missing_ok=True)  # (this process is the run's one writer)


class AtomicTensorBoardLogger(TensorBoardLogger):
    """TensorBoardLogger whose ``hparams.yaml`` is written atomically (event files are
    append-only logs: TensorBoard reads a file cut short up to its last whole record)."""

    @rank_zero_only
    def save(self) -> None:
        folder = Path(self.log_dir)
        hparams_file = folder / self.NAME_HPARAMS_FILE
        if _local(folder) and folder.is_dir() and not hparams_file.exists():
            with atomic_path(hparams_file, overwrite=True) as tmp:
                save_hparams_to_yaml(tmp, self.hparams)
        super().save()  # flushes the events; finds hparams.yaml written
