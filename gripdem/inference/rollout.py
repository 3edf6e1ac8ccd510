"""Chained rollouts of a trained model beyond its horizon, with divergence checks.

A model predicts ``f`` frames (its horizon) from a window of ``K + 1`` observed frames. A
rollout of ``n`` frames chains such predictions: the predicted frames become the history of the
next window (``step`` frames per link, at most ``f``), until ``n`` frames exist. Each window is
built by the same code as training and test windows
(:class:`~gripdem.data.datamodule.WindowDataset` and
:func:`~gripdem.data.batch.collate_windows`), reading its frames from an in-memory buffer of
observed and predicted frames instead of the file. The target fields of these batches are not
the truth (the frames after the last observed one are a copy of it while unknown); the model
never reads them.

Divergence is flagged per predicted frame, never raised:

- ``non_finite``: NaN or Inf positions; the rollout stops at the last finite frame (a NaN
  history cannot be continued);
- ``escaped``: particles whose frame-to-frame step exceeds ``ESCAPE_FRACTION`` of the smallest
  box length (they have left the box in a way no image can follow);
- ``overlap``: the fraction of particles with a neighbour closer than 0.98 d exceeds the
  observed frame's by more than ``overlap_margin``.

Shapes: ``S`` simulations rolled out together (one batch), ``N`` particles, positions
``(S, frames, N, 3)`` wrapped float64, times ``(S, frames)`` absolute.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from gripdem.boundary import displacement
from gripdem.data.batch import collate_windows
from gripdem.data.dataset import WindowDataset
from gripdem.data.schema import DatasetMeta
from gripdem.data.windows import Segment, WindowIndex
from gripdem.evaluation.physics import overlap_fraction

#: a predicted step longer than this fraction of the smallest box length counts as an escape
ESCAPE_FRACTION = 0.25
#: default: flag overlap once this many more particles overlap than at the observed frame
OVERLAP_MARGIN = 0.05


class _BufferReader:
    """Frames from memory with the file reader's interface (``read(sim, start, stop)``)."""

    def __init__(self, positions: np.ndarray):
        self.positions = positions

    def read(self, sim: int, start: int, stop: int) -> np.ndarray:
        return self.positions[sim, start:stop]

    def close(self) -> None:
        pass


@dataclass
class Divergence:
    """Per predicted frame ``(n,)``: ``max_step_over_d`` (largest frame-to-frame step of any
    particle, in diameters), ``escaped`` (particle count), ``overlap`` (fraction of particles
    with a neighbour closer than 0.98 d; empty when not checked); ``first``: flag name ->
    first predicted frame (1-based) where it was raised; ``stopped``: why the rollout ended
    early (None if it did not)."""

    max_step_over_d: list[float] = field(default_factory=list)
    escaped: list[int] = field(default_factory=list)
    overlap: list[float] = field(default_factory=list)
    overlap_start: float = 0.0
    first: dict[str, int] = field(default_factory=dict)
    stopped: str | None = None

    def lines(self, overlap_margin: float) -> list[str]:
        if not self.first:
            return ["no divergence flagged (finite, no escapes, overlap within the margin)"]
        out = []
        for flag, frame in sorted(self.first.items(), key=lambda kv: kv[1]):
            what = {
                "non_finite": "non-finite positions (rollout stopped before this frame)",
                "escaped": f"a particle stepped more than {ESCAPE_FRACTION:g} of the box",
                "overlap": f"overlap fraction above the observed {self.overlap_start:.3f} + "
                f"{overlap_margin:g}",
            }[flag]
            out.append(f"predicted frame {frame}: {what}")
        return out


@dataclass
class Rollout:
    """Observed ``K + 1`` frames followed by the predicted ones (``n_predicted`` of them)."""

    positions: np.ndarray
    times: np.ndarray
    n_observed: int
    divergence: Divergence

    @property
    def n_predicted(self) -> int:
        return self.positions.shape[1] - self.n_observed

    @property
    def predicted(self) -> np.ndarray:
        """``(S, n_predicted, N, 3)``."""
        return self.positions[:, self.n_observed :]


def _record(
    div: Divergence, frames: np.ndarray, before: np.ndarray, offsets, meta: DatasetMeta, j0: int
):
    """Divergence checks of predicted frames ``(S, m, N, 3)`` (``before``: the frame preceding
    them, ``offsets`` ``(S, m)``); ``j0``: 1-based index of the first. Returns the number of
    leading finite frames."""
    box, d = meta.box, meta.diameter
    for j in range(frames.shape[1]):
        frame = frames[:, j]
        if not np.isfinite(frame).all():
            div.first.setdefault("non_finite", j0 + j)
            div.stopped = f"non-finite positions at predicted frame {j0 + j}"
            return j
        step = displacement(frame, before, box, offsets[:, j, None])
        size = np.sqrt((step**2).sum(-1))
        escaped = int((size > ESCAPE_FRACTION * float(box.lengths.min())).sum())
        div.max_step_over_d.append(float(size.max() / d))
        div.escaped.append(escaped)
        if escaped:
            div.first.setdefault("escaped", j0 + j)
        before = frame
    return frames.shape[1]


def _window_batch(buffer, times, meta, model, start: int, k: int, f: int):
    """The batch of the windows that start at buffer frame ``start`` (one per simulation)."""
    windows = WindowIndex([Segment(s, start, 1, 1) for s in range(buffer.shape[0])], k, f)
    dataset = WindowDataset(
        _BufferReader(buffer),
        meta,
        times,
        windows,
        model.encoding,
        model.normalizer,
        float(model.hparams.graph_cutoff) * meta.diameter,
        graph_cache_mb=0.0,
    )
    return collate_windows([dataset[i] for i in range(len(dataset))])


@torch.no_grad()
def rollout(
    model,
    meta: DatasetMeta,
    observed: np.ndarray,
    observed_times: np.ndarray,
    frames: int,
    step: int | None = None,
    overlap_margin: float = OVERLAP_MARGIN,
    check_overlap: bool = True,
    device: str = "cpu",
) -> Rollout:
    """Roll ``model`` out for ``frames`` frames after the ``K + 1`` observed frames
    ``(S, K+1, N, 3)`` (times ``(S, K+1)``), ``step`` predicted frames per link (default: the
    model's horizon). Stops early only at non-finite positions."""
    k, f = int(model.hparams.history_len), int(model.hparams.horizon)
    step = f if step is None else int(step)
    if not 1 <= step <= f:
        raise ValueError(f"--step must lie in 1..{f} (the model's horizon), got {step}")
    if observed.shape[1] != k + 1:
        raise ValueError(f"the model reads {k + 1} observed frames, got {observed.shape[1]}")
    model.eval().to(device)
    s, _, n, _ = observed.shape
    total = k + 1 + frames
    dt = meta.frame_interval
    times = observed_times[:, -1:] + dt * np.arange(-k, total + f - k)[None, :]
    times[:, : k + 1] = observed_times
    buffer = np.empty((s, total + f, n, 3))
    buffer[:, : k + 1] = observed
    offsets = meta.boundary.offset(times)
    div = Divergence()
    if check_overlap:
        last = observed[:, -1]
        div.overlap_start = float(
            np.mean(
                [
                    overlap_fraction(last[i], meta.box, meta.diameter, offsets[i, k])
                    for i in range(s)
                ]
            )
        )
    done = 0
    while done < frames and div.stopped is None:
        start = done  # the window's first frame: its last observed frame is start + k
        buffer[:, start + k + 1 : start + k + 1 + f] = buffer[:, start + k, None]
        batch = _window_batch(buffer, times, meta, model, start, k, f).to(device)
        predicted = model.decode(model(batch), batch).cpu().numpy()  # (S, f, N, 3)
        m = min(step, frames - done)
        at = start + k + 1
        good = _record(
            div, predicted[:, :m], buffer[:, at - 1], offsets[:, at : at + m], meta, done + 1
        )
        buffer[:, at : at + good] = predicted[:, :good]
        if check_overlap:
            for j in range(good):
                value = float(
                    np.mean(
                        [
                            overlap_fraction(
                                predicted[i, j], meta.box, meta.diameter, offsets[i, at + j]
                            )
                            for i in range(s)
                        ]
                    )
                )
                div.overlap.append(value)
                if value > div.overlap_start + overlap_margin:
                    div.first.setdefault("overlap", done + j + 1)
        done += good
    end = k + 1 + done
    return Rollout(buffer[:, :end].copy(), times[:, :end].copy(), k + 1, div)
