"""The in-memory stepper: a trained model advanced frame after frame with its state in memory.

State per simulation: the last ``K + 1`` frames (wrapped, float64), their absolute times (the
LE offsets follow from them in float64), and a neighbour list with a skin
(:class:`gripdem.boundary.NeighbourList`, LE-aware, rebuilt only when a pair outside it could
have come within the cut-off). One *link* is one forward pass of the model: its inputs are built
from the state (steps, normalisation, the graph from the neighbour list), it predicts its
horizon ``f``, and the first ``link <= f`` frames are kept. Each kept frame then

1. is moved by the corrections of the frames before it in the link (a corrected particle keeps
   its new position; the model's velocity for it stays), and wrapped with its own offset;
2. moves the neighbour list to it and, with ``contact_correction``, has its overlapping pairs
   pushed apart (:mod:`gripdem.inference.contacts`);
3. joins the state as the newest frame.

No HDF5 read and no dataset object per link: :func:`gripdem.inference.rollout.rollout`,
``gripdem.predict``, the runner's test step and the benchmarks all step through here.
:attr:`Stepper.seconds` accumulates the wall time of each part (neighbour list, features,
forward, decode and wrap, correction).

Shapes: ``S`` simulations advanced together (one batch), ``N`` particles; frames
``(S, frames, N, 3)``, times ``(S, frames)``.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from gripdem.boundary import NeighbourList, minimum_image, wrap_positions
from gripdem.data.batch import inference_batch
from gripdem.data.graph import graph_from_pairs
from gripdem.inference.contacts import (
    CORRECTION_TOLERANCE,
    Correction,
    push_apart,
    resting_overlap,
)
from gripdem.inference.precision import resolve_precision, with_encoder_precision
from gripdem.models.ensemble import check_contact_capture

PARTS = ("neighbour_list", "features", "forward", "decode_wrap", "correction", "relaxation")


@dataclass
class StepperSettings:
    """How a model is advanced (the stable setting is the default of predict and the runner).

    link: frames kept per forward pass (None: the model's horizon). contact_correction: push
    overlapping pairs apart after every frame; contact_distance: the closest centre distance
    allowed, in diameters; correction_sweeps: at most this many Gauss-Seidel sweeps;
    correction_tolerance: overlaps smaller than this fraction of the contact distance are left
    (the sweeps stop when none is larger; the DEM's own reach ~1e-5-1e-4 d). skin: of the
    neighbour list, in diameters. compile: the encoder through ``torch.compile`` (pays for long
    rollouts: seconds of compilation, then a faster forward; falls back with a warning where no
    compiler works). relaxation: a callable ``(previous (N, 3), frame (N, 3), times (2,)) ->
    frame`` applied to every predicted frame before anything else (the hybrid surrogate,
    :class:`gripdem.inference.relaxation.DemRelaxation`; None: off). precision: of the
    encoder (auto | fp32 | bf16, :mod:`gripdem.inference.precision`; auto: bf16 where the
    device computes it natively); the stepper then runs a copy of the model, the model passed
    in is left as it was. contact_capture: pairs closer than this gap (contact distances) are
    pulled into contact by the correction (the cohesion's snap,
    :mod:`gripdem.inference.contacts`; 0: off; needs
    ``contact_correction``; None: the model's own ``contact_capture`` hyperparameter, off without
    correction).
    """

    link: int | None = None
    contact_correction: bool = True
    contact_distance: float = 1.0
    correction_sweeps: int = 50
    correction_tolerance: float = CORRECTION_TOLERANCE
    skin: float = 0.3
    compile: bool = False
    relaxation: object | None = None
    precision: str = "fp32"
    contact_capture: float | None = None
    contact_overlap: float | None = None

    def __post_init__(self):
        if self.contact_overlap is not None and not (
            0.0 <= float(self.contact_overlap) < self.correction_tolerance
        ):
            raise ValueError(
                f"contact_overlap is where corrected pairs end, a fraction of the contact "
                f"distance in [0, correction_tolerance = {self.correction_tolerance:g}), got "
                f"{self.contact_overlap}"
            )
        if self.contact_capture is None:
            return
        check_contact_capture(self.contact_capture, "contact_capture")
        if self.contact_capture and not self.contact_correction:
            raise ValueError(
                "contact_capture works inside the contact correction: it needs "
                "contact_correction on (no relaxation, no --no-correction)"
            )

    def to_dict(self) -> dict:
        out = dict(self.__dict__)
        out["relaxation"] = None if self.relaxation is None else str(self.relaxation)
        return out


@dataclass
class StepReport:
    """Per kept frame: the correction's counts (empty lists without correction)."""

    overlapping_before: list[int] = field(default_factory=list)
    worst_overlap_before: list[float] = field(default_factory=list)
    overlapping_after: list[int] = field(default_factory=list)
    rms_push_over_d: list[float] = field(default_factory=list)
    pulled: list[int] = field(default_factory=list)


class Stepper:
    """Advance ``model`` from ``observed`` frames ``(S, K+1, N, 3)`` at ``times (S, K+1)``."""

    def __init__(self, model, observed: np.ndarray, times: np.ndarray, settings=None):
        self.settings = settings or StepperSettings()
        self.precision = resolve_precision(self.settings.precision, next(model.parameters()).device)
        model = with_encoder_precision(model, self.precision)
        self.model = model.eval()
        if self.settings.compile:
            compile_encoder(model)
        self.stopped: str | None = None
        #: the newest kept frame's step from the frame before it ``(S, N, 3)`` (minimum image)
        self.last_steps: np.ndarray | None = None
        self._pending: list | None = None  # the current link: frames, times, offsets, next, carry
        self.k = int(model.hparams.history_len)
        self.f = int(model.hparams.horizon)
        self.link = self.f if self.settings.link is None else int(self.settings.link)
        if not 1 <= self.link <= self.f:
            raise ValueError(f"link must lie in 1..{self.f} (the model's horizon), got {self.link}")
        self.boundary = model.boundary
        self.box = model.boundary.box
        self.d = float(model.diameter)
        self.dt = float(model.hparams.scene["frame_interval"])
        self.cutoff = float(model.hparams.graph_cutoff) * self.d
        self.radius = max(self.cutoff, self.settings.contact_distance * self.d)
        own = check_contact_capture(
            model.hparams.get("contact_capture", 0.0), "the model's contact_capture"
        )
        given = self.settings.contact_capture
        self.capture = (
            (own if given is None else given) if self.settings.contact_correction else 0.0
        )
        self.set_state(observed, times)
        self.seconds = dict.fromkeys(PARTS, 0.0)
        self.report = StepReport()
        self.n_predicted = 0
        self.device = next(model.parameters()).device

    def set_state(self, observed: np.ndarray, times: np.ndarray) -> None:
        """Continue from ``observed`` frames ``(S, K+1, N, 3)`` at ``times`` ``(S, K+1)``
        instead of the state so far (a coupled code hands its state back): the neighbour
        lists are rebuilt at the newest frame and a link in progress is dropped. The number
        of simulations may not change; timings and the correction report keep accumulating."""
        observed = np.asarray(observed, dtype=np.float64)
        times = np.asarray(times, dtype=np.float64)
        if observed.ndim != 4 or observed.shape[1] != self.k + 1 or observed.shape[-1] != 3:
            raise ValueError(
                f"the model reads {self.k + 1} observed frames: expected (sims, {self.k + 1}, "
                f"particles, 3), got {observed.shape}"
            )
        if times.shape != observed.shape[:2]:
            raise ValueError(
                f"times must be {observed.shape[:2]} (sims, frames), got {times.shape}"
            )
        if hasattr(self, "frames") and len(observed) != len(self.frames):
            raise ValueError(
                f"a state of {len(self.frames)} simulations expected, got {len(observed)}"
            )
        if not (np.isfinite(observed).all() and np.isfinite(times).all()):
            raise ValueError("the state's positions and times must be finite (NaN or Inf found)")
        self.frames = observed.copy()
        self.times = times.copy()
        self.lists = [
            NeighbourList(
                self.box, self.radius, self.settings.skin * self.d, self.boundary.image_velocity
            )
            for _ in range(len(observed))
        ]
        for s, nl in enumerate(self.lists):
            nl.build(
                self.frames[s, -1], float(self.offsets(self.times[s, -1:])[0]), self.times[s, -1]
            )
        distance = self.settings.contact_distance * self.d
        tolerance = self.settings.correction_tolerance
        self.overlap = self.settings.contact_overlap
        if self.overlap is None:  # the observed frames' resting contacts (first simulation's)
            self.overlap = resting_overlap(self.lists[0], self.times[0, -1], distance, tolerance)
        self._pending = None
        self.stopped = None

    def offsets(self, times: np.ndarray) -> np.ndarray:
        return self.boundary.offset(times)

    @property
    def n_sims(self) -> int:
        return self.frames.shape[0]

    # ---- one forward pass -----------------------------------------------------------------
    def _batch(self):
        """The model's input batch from the state (no targets)."""
        s, _, n, _ = self.frames.shape
        future = self.times[:, -1:] + self.dt * np.arange(1, self.f + 1)[None, :]
        times = np.concatenate([self.times, future], axis=1)
        offsets = self.offsets(times)
        positions = self.frames.transpose(0, 2, 1, 3)  # (S, N, K+1, 3)
        encoding = self.model.encoding
        le = self.boundary.is_lees_edwards
        steps = encoding.encode(positions, offsets[:, : self.k + 1] if le else None, anchor=self.k)
        inputs = self.model.normalizer.normalize(steps).astype(np.float32)
        graphs = []
        for sim, nl in enumerate(self.lists):
            i, j, vec = nl.pairs(self.times[sim, -1], self.cutoff)
            graphs.append(graph_from_pairs(i, j, vec, n, length_unit=self.d))
        return inference_batch(inputs, positions, times, offsets, graphs)

    def link_batch(self):
        """The next link's input batch from the state, on the model's device (what the model
        reads to predict the link; no targets). Rollout training computes the model's output
        on it with gradient and hands it back through :meth:`take_link`."""
        started = time.perf_counter()
        batch = self._batch()
        self.seconds["features"] += time.perf_counter() - started
        return batch.to(self.device)

    @torch.no_grad()
    def take_link(self, batch, outputs: torch.Tensor) -> None:
        """Make the model's ``outputs`` for :meth:`link_batch`'s ``batch`` the next link: the
        following :meth:`advance` keeps its frames (corrected) instead of predicting one."""
        if self._pending is not None and self._pending[3] < self.link:
            raise RuntimeError(
                f"take_link: {self.link - self._pending[3]} frames of the current link are not "
                "kept yet (advance first)"
            )
        started = time.perf_counter()
        predicted = self.model.decode(outputs.detach(), batch).cpu().numpy()
        self.seconds["decode_wrap"] += time.perf_counter() - started
        future_times = batch.times[:, self.k + 1 :].cpu().numpy()
        future_offsets = batch.offsets[:, self.k + 1 :].cpu().numpy()
        self._pending = [predicted, future_times, future_offsets, 0, np.zeros_like(predicted[:, 0])]

    @torch.no_grad()
    def _predict(self) -> None:
        """One link predicted from the state (:meth:`link_batch`, the forward pass,
        :meth:`take_link`)."""
        batch = self.link_batch()
        started = time.perf_counter()
        out = self.model(batch)
        self.seconds["forward"] += time.perf_counter() - started
        self.take_link(batch, out)

    # ---- frames ---------------------------------------------------------------------------
    def _accept(
        self, frame: np.ndarray, times: np.ndarray, offsets: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Move the lists to a predicted frame ``(S, N, 3)``, correct it, add it to the state;
        returns the frame as kept and how far the relaxation and the correction moved each
        particle ``(S, N, 3)`` (the carry of the link's later frames)."""
        moved = np.zeros_like(frame)
        if self.settings.relaxation is not None:
            started = time.perf_counter()
            relaxed = frame.copy()
            for sim in range(len(frame)):
                pair_times = np.array([self.times[sim, -1], times[sim]])
                relaxed[sim] = self.settings.relaxation(
                    self.frames[sim, -1], frame[sim], pair_times
                )
            moved += minimum_image(relaxed - frame, self.box, offsets[:, None])
            frame = relaxed
            self.seconds["relaxation"] += time.perf_counter() - started
        kept = frame.copy()
        self.last_steps = np.empty_like(frame)
        for sim, nl in enumerate(self.lists):
            started = time.perf_counter()
            before, builds = nl.q, nl.builds  # the previous kept frame's physical images
            nl.update(frame[sim], float(offsets[sim]), float(times[sim]))
            self.seconds["neighbour_list"] += time.perf_counter() - started
            if self.settings.contact_correction:
                started = time.perf_counter()
                corr = self._correct(nl, float(times[sim]), float(offsets[sim]), moved[sim])
                self._record(corr, sim)
                kept[sim] = wrap_positions(nl.q, self.box, float(offsets[sim]))
                self.seconds["correction"] += time.perf_counter() - started
            if nl.builds == builds:  # the same images followed: the step is their difference
                self.last_steps[sim] = nl.q - before
            else:
                last = self.frames[sim, -1]
                self.last_steps[sim] = minimum_image(kept[sim] - last, self.box, offsets[sim])
        self.frames = np.concatenate([self.frames[:, 1:], kept[:, None]], axis=1)
        self.times = np.concatenate([self.times[:, 1:], times[:, None]], axis=1)
        return kept, moved

    def _correct(
        self, nl: NeighbourList, time: float, offset: float, moved: np.ndarray
    ) -> Correction:
        """Push overlapping pairs apart (and pull captured pairs into contact), adding each
        particle's move to ``moved`` ``(N, 3)``; when the moves made the list stale, rebuild it
        at the corrected frame and correct again (pairs it did not list may touch now)."""
        distance = self.settings.contact_distance * self.d
        sweeps, tolerance = self.settings.correction_sweeps, self.settings.correction_tolerance
        pulls = (self.capture, self.overlap)
        corr = push_apart(nl, time, distance, sweeps, tolerance, *pulls)
        moved += corr.moves
        if nl.stale(nl.q, time):
            nl.build(wrap_positions(nl.q, self.box, offset), offset, time)
            again = push_apart(nl, time, distance, sweeps, tolerance, *pulls)
            moved += again.moves
            corr.overlapping_after, corr.worst_after = again.overlapping_after, again.worst_after
        return corr

    def _record(self, corr: Correction, sim: int) -> None:
        if sim == 0:  # per frame: summed over the simulations
            for name in ("overlapping_before", "worst_overlap_before", "overlapping_after"):
                getattr(self.report, name).append(0)
            self.report.rms_push_over_d.append(0.0)
            self.report.pulled.append(0)
        r = self.report
        r.overlapping_before[-1] += corr.overlapping_before
        r.worst_overlap_before[-1] = max(r.worst_overlap_before[-1], corr.worst_before)
        r.overlapping_after[-1] += corr.overlapping_after
        r.rms_push_over_d[-1] += corr.rms_push / self.d / self.n_sims
        r.pulled[-1] += corr.pulled

    def advance(self, count: int) -> np.ndarray:
        """Predict ``count`` more frames; returns them ``(S, count, N, 3)`` as kept, or fewer
        when the model predicts a non-finite position (:attr:`stopped` then says where). A link
        is predicted when the previous one's kept frames are used up, so frames can be asked
        for one at a time at no extra cost."""
        out = []
        while len(out) < count and self.stopped is None:
            if self._pending is None or self._pending[3] >= self.link:
                self._predict()
            predicted, times, offsets, j, carry = self._pending
            moved = predicted[:, j] + carry
            if not np.isfinite(moved).all():
                self.stopped = f"non-finite positions predicted {self.n_predicted + 1} frames in"
                break
            frame = wrap_positions(moved, self.box, offsets[:, j, None])
            kept, corrected = self._accept(frame, times[:, j], offsets[:, j])
            self._pending[4] = carry + corrected
            self._pending[3] = j + 1
            self.n_predicted += 1
            out.append(kept)
        if not out:
            return np.zeros(self.frames.shape[:1] + (0,) + self.frames.shape[2:])
        return np.stack(out, axis=1)


def compile_encoder(model) -> bool:
    """``model.encoder`` through ``torch.compile`` (dynamic shapes: the edge count changes every
    link); returns whether it worked. A model is compiled once."""
    if getattr(model, "_compiled_encoder", False):
        return True
    try:
        compiled = torch.compile(model.encoder, dynamic=True)
        model.encoder = compiled
        model._compiled_encoder = True
    except Exception as exc:  # no C++ compiler, an unsupported platform: stay eager
        warnings.warn(f"torch.compile unavailable, the encoder stays eager: {exc}", stacklevel=2)
        return False
    return True
