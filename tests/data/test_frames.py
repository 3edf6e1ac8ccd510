"""Windows from memory (``gripdem.data.frames``: each simulation read once, its steps and skin
neighbour lists prepared once) equal windows read from the file, field by field, on the built-in
DEM's tiny scenes: every part, both scenes, LE crossings included, graphs as sets of edges."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gripdem.data.batch import collate_windows
from gripdem.data.datamodule import TrajectoryDataModule


def module(path, memory_mb: float, encoding: str) -> TrajectoryDataModule:
    dm = TrajectoryDataModule(
        path,
        split="20-5",
        history_len=10,
        encoding=encoding,
        graph_cutoff=1.3,
        graph_cache_mb=0.0,  # every graph built, never a cached one
        memory_mb=memory_mb,
    )
    dm.setup("fit")
    return dm


def edges(batch) -> tuple[np.ndarray, np.ndarray]:
    """Every edge as (receiver, neighbour) pairs ``(E, 2)``, sorted, with its (vector,
    distance, gap, weight) ``(E, 6)`` in the same order: a graph as a set of edges."""
    pairs = batch.edge_index.numpy().T
    values = np.column_stack(
        [
            batch.edge_vector.double().numpy(),
            batch.edge_distance.double().numpy(),
            batch.edge_gap.double().numpy(),
            batch.edge_weight.double().numpy(),
        ]
    )
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order], values[order]


@pytest.mark.parametrize("scene", ["pbc", "lebc"])
def test_windows_from_memory_equal_windows_from_the_file(request, scene):
    encoding = "unwrapped"  # the store serves the exact frame; the paper's encodings read the file
    path = request.getfixturevalue(f"tiny_{scene}_path")
    from_file, from_memory = module(path, 0.0, encoding), module(path, 2048.0, encoding)
    crossers = 0
    for part in ("train", "val", "test"):
        a_set, b_set = from_file.datasets[part], from_memory.datasets[part]
        assert len(a_set) == len(b_set) > 0
        for k in range(0, len(a_set), max(1, len(a_set) // 6)):  # spread over the part
            a, b = collate_windows([a_set[k]]), collate_windows([b_set[k]])
            for name in ("inputs", "target_deltas", "input_positions", "target_positions",
                         "times", "offsets", "crossing_mask"):  # fmt: skip
                x, y = getattr(a, name), getattr(b, name)
                if x.dtype == torch.bool:
                    assert torch.equal(x, y), (part, k, name)
                else:
                    torch.testing.assert_close(y, x, rtol=1e-6, atol=1e-9, msg=(part, k, name))
            (pairs_a, values_a), (pairs_b, values_b) = edges(a), edges(b)
            np.testing.assert_array_equal(pairs_b, pairs_a, err_msg=f"{part} {k}")
            np.testing.assert_allclose(values_b, values_a, rtol=1e-6, atol=1e-9)
            crossers += int(a.crossing_mask.sum())
    assert (crossers > 0) == (scene == "lebc")  # the LE windows do cross x faces
    assert from_memory.datasets["train"].store is not None
    assert from_file.datasets["train"].store is None or not from_file.datasets["train"].store.fits
