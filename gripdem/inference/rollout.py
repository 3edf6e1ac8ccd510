"""Chained rollouts of a trained model beyond its horizon, with divergence checks.

A model predicts ``f`` frames (its horizon) from a window of ``K + 1`` observed frames. A
rollout of ``n`` frames chains such predictions with the in-memory
:class:`~gripdem.inference.stepper.Stepper`: the predicted (and, in the stable setting,
contact-corrected) frames become the history of the next link (``link`` frames per forward
pass, at most ``f``), until ``n`` frames exist.

Divergence is flagged per predicted frame, never raised:

- ``non_finite``: NaN or Inf positions; the rollout stops at the last finite frame (a NaN
  history cannot be continued);
- ``escaped``: particles whose frame-to-frame step exceeds ``ESCAPE_FRACTION`` of the smallest
  box length (they have left the box in a way no image can follow);
- ``overlap``: the fraction of particles with a neighbour closer than 0.98 d (in the frames as
  kept, after any contact correction; the model's own overlaps before the correction are in
  the stepper's report) exceeds the observed frame's by more than ``overlap_margin``.

An ensemble model (one whose forward pass draws latent noise) rolls out ``members`` members
from every observed window: the observed frames are repeated, so member ``m`` of simulation
``s`` is row ``s * members + m`` of the batch, each an independent sample advanced and
contact-corrected like any trajectory; ``seed`` makes the draws reproducible.

Shapes: ``S`` simulations rolled out together (one batch; ``S * members`` rows for an
ensemble), ``N`` particles, positions ``(rows, frames, N, 3)`` wrapped float64, times
``(rows, frames)`` absolute.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import torch

from gripdem.data.schema import DatasetMeta
from gripdem.evaluation.physics import OVERLAP_TOLERANCE
from gripdem.inference.rollout_limits import ESCAPE_FRACTION, OVERLAP_MARGIN
from gripdem.inference.stepper import Stepper, StepperSettings

#: bytes a rollout holds per kept position value: the frames as kept, their concatenation and
#: the copies a caller's scores make (float64, about 3 copies)
BYTES_PER_POSITION = 3 * 8


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``; None where the
    system does not say)."""
    try:
        with open("/proc/meminfo") as info:
            for line in info:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


def check_members_fit(members: int, sims: int, frames: int, particles: int) -> None:
    """Refuse (ValueError naming ``members`` and the most that fit) an ensemble whose kept
    trajectories ``members * sims`` rows of ``frames`` frames of ``particles`` positions would
    not fit in the memory available now."""
    free = available_memory()
    if free is None or members <= 1:
        return
    per_member = int(sims) * int(frames) * int(particles) * 3 * BYTES_PER_POSITION
    if members * per_member > free:
        most = max(free // per_member, 1)
        raise ValueError(
            f"members {members}: {members} x {sims} simulation(s) x {frames} frames x "
            f"{particles} particles need about {members * per_member / 2**30:.1f} GiB, "
            f"{free / 2**30:.1f} GiB are available: at most {most} members fit (1..{most})"
        )


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
    stepper: Stepper | None = None
    members: int = 1

    @property
    def n_sims(self) -> int:
        return self.positions.shape[0] // self.members

    @property
    def n_predicted(self) -> int:
        return self.positions.shape[1] - self.n_observed

    @property
    def predicted(self) -> np.ndarray:
        """``(S * members, n_predicted, N, 3)`` (member ``m`` of sim ``s`` in row
        ``s * members + m``)."""
        return self.positions[:, self.n_observed :]

    def by_member(self, frames: np.ndarray) -> np.ndarray:
        """Rows ``(S * members, ...)`` -> ``(S, members, ...)``."""
        return frames.reshape((self.n_sims, self.members) + frames.shape[1:])


def _record(div: Divergence, frame: np.ndarray, steps: np.ndarray, meta: DatasetMeta, j: int):
    """Divergence checks of the predicted frame ``(S, N, 3)`` and its steps from the frame
    before it ``(S, N, 3)`` (minimum image); ``j``: its 1-based index. Returns whether it is
    finite."""
    if not np.isfinite(frame).all():
        div.first.setdefault("non_finite", j)
        div.stopped = f"non-finite positions at predicted frame {j}"
        return False
    size = np.sqrt(np.einsum("snc,snc->sn", steps, steps))
    escaped = int((size > ESCAPE_FRACTION * float(meta.box.lengths.min())).sum())
    div.max_step_over_d.append(float(size.max() / meta.diameter))
    div.escaped.append(escaped)
    if escaped:
        div.first.setdefault("escaped", j)
    return True


def overlap_fraction(stepper: Stepper, tolerance: float = OVERLAP_TOLERANCE) -> float:
    """Fraction of particles with a neighbour closer than ``tolerance`` d at the stepper's
    newest frame (from its neighbour lists: no new search), mean over the simulations."""
    fractions = []
    for sim, nl in enumerate(stepper.lists):
        i, j, _ = nl.pairs(stepper.times[sim, -1], tolerance * stepper.d)
        touched = np.zeros(len(nl.q), dtype=bool)
        touched[i] = touched[j] = True
        fractions.append(touched.mean())
    return float(np.mean(fractions))


def rollout(
    model,
    meta: DatasetMeta,
    observed: np.ndarray,
    observed_times: np.ndarray,
    frames: int,
    settings: StepperSettings | None = None,
    overlap_margin: float = OVERLAP_MARGIN,
    check_overlap: bool = True,
    members: int = 1,
    seed: int | None = None,
) -> Rollout:
    """Roll ``model`` out for ``frames`` frames after the ``K + 1`` observed frames
    ``(S, K+1, N, 3)`` (times ``(S, K+1)``) with the in-memory :class:`Stepper` (``settings``:
    link length, contact correction; default the stable setting). Stops early only at
    non-finite positions. The model must already be on its device. An ensemble model rolls
    out ``members`` members per simulation, its noise drawn from a generator seeded with
    ``seed`` (None: torch's global generator); ``members`` beyond the memory available are
    refused before anything is computed."""
    observed, observed_times = ensemble_start(
        model, observed, observed_times, members, seed, frames
    )
    stepper = Stepper(model, observed, observed_times, settings)
    k = stepper.k
    div = Divergence()
    if check_overlap:
        div.overlap_start = overlap_fraction(stepper)
    kept = [np.asarray(observed, dtype=np.float64)]
    times = [np.asarray(observed_times, dtype=np.float64)]
    done = 0
    while done < frames:
        new = stepper.advance(1)
        if new.shape[1]:
            _record(div, new[:, 0], stepper.last_steps, meta, done + 1)
            kept.append(new)
            times.append(stepper.times[:, -1:].copy())
            if check_overlap:
                value = overlap_fraction(stepper)
                div.overlap.append(value)
                if value > div.overlap_start + overlap_margin:
                    div.first.setdefault("overlap", done + 1)
            done += 1
        if stepper.stopped is not None:
            div.first.setdefault("non_finite", done + 1)
            div.stopped = stepper.stopped
            break
    positions = np.concatenate(kept, axis=1)
    return Rollout(positions, np.concatenate(times, axis=1), k + 1, div, stepper, int(members))


def ensemble_start(
    model, observed, observed_times, members: int, seed: int | None, frames: int = 0
):
    """The observed frames and times repeated ``members`` times per simulation (member-minor
    rows), and the model's noise generator seeded; a deterministic model accepts only one
    member, and members whose ``frames`` more frames would not fit in memory are refused."""
    members = int(members)
    if members < 1:
        raise ValueError(f"members must be >= 1, got {members}")
    if not getattr(model, "is_ensemble", False):
        if members > 1:
            raise ValueError(
                f"this model is deterministic (no latent noise): it has no ensemble, so it "
                f"rolls out one member, not {members} (--members 1)"
            )
        return observed, observed_times
    shape = np.shape(observed)  # the members' rows of frames + K + 1 frames must fit
    check_members_fit(members, shape[0], shape[1] + int(frames), shape[2])
    device = next(model.parameters()).device
    generator = torch.Generator(device=device)
    if seed is None:
        generator.seed()
    else:
        generator.manual_seed(int(seed))
    model.noise_generator = generator
    return (
        np.repeat(np.asarray(observed, np.float64), members, axis=0),
        np.repeat(np.asarray(observed_times, np.float64), members, axis=0),
    )
