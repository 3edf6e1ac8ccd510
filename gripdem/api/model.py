"""A trained model from Python: load it, roll it out, or step it inside your own code.

torch and the model code are imported by ``load_model``, not before.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gripdem.api.scene import Scene, Trajectory

#: time steps of history and prediction may differ from the scene's frame interval by this
TIME_RTOL = 1e-4


def load_model(source: str | os.PathLike, device: str = "cpu", precision: str = "auto") -> Model:
    """Load a trained model: ``"pretrained:pbc"``, ``"pretrained:lebc"``, a run's
    ``checkpoints/best.safetensors`` or a Lightning ``.ckpt``.

    Files are read as data (safetensors with a JSON card; nothing is unpickled). ``device``:
    a torch device (``"cpu"``, ``"cuda"``). ``precision``: of the encoder, ``"auto"`` (the
    default of ``gripdem.predict``: bf16 where the device computes it natively, CPU
    avx512_bf16/AMX or CUDA 8.0+, else fp32), ``"fp32"`` or ``"bf16"``."""
    from gripdem.inference.checkpoint import read_checkpoint
    from gripdem.inference.pretrained import resolve

    path = resolve(source)
    hparams, state, card = read_checkpoint(path)
    return Model(str(source), path, hparams, state, dict(card), device, precision)


@dataclass
class RolloutResult:
    """A rollout: the observed frames, then the predicted ones.

    Shapes: ``batch`` is ``()`` for a history of one simulation ``(frames, N, 3)`` and
    ``(S,)`` for ``(S, frames, N, 3)``; with ``members > 1`` a members axis follows it.

    Attributes:
        positions: ``(*batch, n_observed + n_predicted, N, 3)`` wrapped, m, float64.
        times: ``(*batch, n_observed + n_predicted)`` absolute, s.
        n_observed: the observed frames at the start (the model's history, ``K + 1``).
        scene: the scene rolled out in.
        divergence: per predicted frame ``max_step_over_d``, ``escaped``, ``overlap``; the
            first frame of each flag (``first``) and why it stopped early (``stopped``).
        correction: per predicted frame the contact correction's counts
            (``overlapping_before``, ``worst_overlap_before``, ``overlapping_after``,
            ``rms_push_over_d``); empty lists without correction.
        timings: seconds spent per part of the stepper (neighbour list, features, forward,
            decode and wrap, correction, relaxation).
        precision: the encoder's arithmetic used.
        notes: what differs between the scene and the model's training scene.
    """

    positions: np.ndarray
    times: np.ndarray
    n_observed: int
    scene: Scene
    members: int = 1
    divergence: dict[str, Any] = field(default_factory=dict)
    correction: dict[str, list] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    precision: str = "fp32"
    notes: list[str] = field(default_factory=list)

    @property
    def predicted(self) -> np.ndarray:
        """The predicted frames only: ``(*batch, n_predicted, N, 3)``."""
        return self.positions[..., self.n_observed :, :, :]

    @property
    def n_predicted(self) -> int:
        """Frames predicted (fewer than asked only when the model produced NaN/Inf)."""
        return self.positions.shape[-3] - self.n_observed

    @property
    def seconds_per_frame(self) -> float:
        """Wall time of the stepper per predicted frame (all simulations together)."""
        return sum(self.timings.values()) / max(self.n_predicted, 1)

    def trajectory(self) -> Trajectory:
        """The rollout as a ``Trajectory`` (rows: simulation-major, then members), to
        write with ``gripdem.api.write_trajectory`` or to report with ``.physics()``."""
        n, t = self.positions.shape[-2], self.positions.shape[-3]
        return Trajectory(
            self.positions.reshape(-1, t, n, 3),
            self.times.reshape(-1, t),
            self.scene,
            provenance={"generator": "gripdem.api", "members": self.members},
        )


class Model:
    """A trained gripdem model (from ``load_model``).

    Attributes:
        source: what it was loaded from.
        path: the model file.
        history_len: ``K``: it reads ``K + 1`` observed frames.
        horizon: ``f``: frames predicted per forward pass (rollouts chain passes).
        scene: the training scene (``Scene``).
        card: the model file's card (training data, split, metrics; empty for a ``.ckpt``).
        is_ensemble: whether it draws latent noise (then ``members > 1`` samples).
    """

    def __init__(self, source, path, hparams, state, card, device="cpu", precision="auto"):
        self.source, self.path = source, Path(path)
        self.hparams, self.card = dict(hparams), card
        self._state = state
        self.device, self.precision = str(device), str(precision)
        self.history_len = int(hparams["history_len"])
        self.horizon = int(hparams["horizon"])
        self.scene = Scene.from_model_scene(hparams["scene"])
        self._modules: dict[Scene, Any] = {}
        self._notes: dict[tuple[Scene, int], list[str]] = {}
        self.is_ensemble = bool(self.module(self.scene).is_ensemble)

    def __repr__(self) -> str:
        return (
            f"Model({self.source!r}: {self.hparams.get('encoding')} encoding, history "
            f"{self.history_len}, horizon {self.horizon}, {self.scene.boundary}, "
            f"{'ensemble' if self.is_ensemble else 'deterministic'})"
        )

    def module(self, scene: Scene | None = None):
        """The LightningModule (``gripdem.models.module.TrajectoryModule``) applied in
        ``scene`` (default: the training scene), on the model's device, in eval mode."""
        scene = self.scene if scene is None else scene
        if scene not in self._modules:
            from gripdem.inference.checkpoint import build_module, data_scene

            meta = scene.to_meta(1, self.history_len + 1, 1)
            built = build_module(self.path, self.hparams, self._state, scene=data_scene(meta))
            self._modules[scene] = built.to(self.device).eval()
        return self._modules[scene]

    def check_scene(self, scene: Scene, particles: int) -> list[str]:
        """Notes on how ``scene`` differs from the training scene; raises a ``ValueError``
        naming the field when the model cannot be applied there."""
        from gripdem.inference.checkpoint import check_compatible

        key = (scene, int(particles))
        if key not in self._notes:  # the model file is read once per scene, not per call
            meta = scene.to_meta(1, self.history_len + 1, particles, path="<scene in memory>")
            self._notes[key] = check_compatible(self.path, meta)[1]
        return list(self._notes[key])

    def _history(self, history, times, scene: Scene):
        """``(observed (S, K+1, N, 3), times (S, K+1), single)`` from the user's arrays."""
        k1 = self.history_len + 1
        positions = np.asarray(history, dtype=np.float64)
        single = positions.ndim == 3
        if single:
            positions = positions[None]
        if positions.ndim != 4 or positions.shape[-1] != 3 or positions.shape[1] < k1:
            raise ValueError(
                f"history: expected (frames >= {k1}, particles, 3) or (sims, frames, particles, "
                f"3) positions (the model reads {k1} frames), got {np.shape(history)}"
            )
        if not np.isfinite(positions).all():
            raise ValueError("history: positions must be finite (NaN or Inf found)")
        if times is None:
            times = scene.times(positions.shape[1])
        times = np.asarray(times, dtype=np.float64)
        times = np.broadcast_to(times, positions.shape[:2]) if times.ndim == 1 else times
        if times.shape != positions.shape[:2]:
            raise ValueError(f"times: expected {positions.shape[:2]}, got {np.shape(times)}")
        times = np.ascontiguousarray(times[:, -k1:])
        steps = np.diff(times, axis=1)
        if not np.allclose(steps, scene.frame_interval, rtol=TIME_RTOL, atol=0.0):
            raise ValueError(
                f"times: the last {k1} frames must be {scene.frame_interval:.6g} s apart (the "
                f"scene's frame_interval), got steps {steps.min():.6g}..{steps.max():.6g} s"
            )
        return np.ascontiguousarray(positions[:, -k1:]), times, single

    def _settings(self, correction, contact_distance, link, precision):
        from gripdem.inference.stepper import StepperSettings

        return StepperSettings(
            link=link,
            contact_correction=bool(correction),
            contact_distance=float(contact_distance),
            precision=self.precision if precision is None else str(precision),
        )

    def rollout(
        self,
        history: np.ndarray,
        times: np.ndarray | None = None,
        *,
        frames: int | None = None,
        scene: Scene | None = None,
        members: int = 1,
        seed: int | None = None,
        correction: bool = True,
        contact_distance: float = 1.0,
        link: int | None = None,
        precision: str | None = None,
        check_overlap: bool = True,
    ) -> RolloutResult:
        """Predict ``frames`` frames (default: the horizon) after ``history``.

        Args:
            history: positions ``(frames, N, 3)`` of one simulation or ``(S, frames, N, 3)``,
                wrapped, m; the last ``K + 1`` frames are read.
            times: absolute times ``(frames,)`` or ``(S, frames)``; default
                ``scene.times(frames)`` (0, dt, 2 dt, ...).
            frames: frames to predict; beyond the horizon the model's own predictions become
                its history.
            scene: where it is applied (default the training scene); a scene beyond 1 % of
                the training scene is refused with the field named.
            members: samples of an ensemble model per simulation (1 for a deterministic one).
            seed: of the ensemble's noise (the same seed, the same members).
            correction: push overlapping particles apart after every frame (the stable
                setting of ``gripdem.predict``).
            contact_distance: the closest centre distance the correction allows, in d.
            link: predicted frames kept per forward pass (default the horizon).
            precision: of the encoder (default the model's, ``load_model``).
            check_overlap: compute the per-frame overlap fraction (divergence check).

        Returns:
            a ``RolloutResult``; identical to ``python -m gripdem.predict`` on the same
            frames (both use ``gripdem.inference.rollout.rollout``).
        """
        from gripdem.inference.rollout import OVERLAP_MARGIN, rollout

        scene = self.scene if scene is None else scene
        observed, obs_times, single = self._history(history, times, scene)
        notes = self.check_scene(scene, observed.shape[2])
        meta = scene.to_meta(len(observed), observed.shape[1], observed.shape[2])
        settings = self._settings(correction, contact_distance, link, precision)
        frames = self.horizon if frames is None else int(frames)
        if frames < 1:
            raise ValueError(f"frames: expected a positive number of frames, got {frames}")
        run = rollout(
            self.module(scene),
            meta,
            observed,
            obs_times,
            frames,
            settings,
            OVERLAP_MARGIN,
            check_overlap,
            members=members,
            seed=seed,
        )
        batch = () if single else (run.n_sims,)
        batch += (run.members,) if run.members > 1 else ()
        div = run.divergence
        report = run.stepper.report
        return RolloutResult(
            positions=run.positions.reshape(batch + run.positions.shape[1:]),
            times=run.times.reshape(batch + run.times.shape[1:]),
            n_observed=run.n_observed,
            scene=scene,
            members=run.members,
            divergence={
                "first": dict(div.first),
                "stopped": div.stopped,
                "max_step_over_d": list(div.max_step_over_d),
                "escaped": list(div.escaped),
                "overlap_start": div.overlap_start,
                "overlap": list(div.overlap),
            },
            correction={k: list(v) for k, v in report.__dict__.items()},
            timings=dict(run.stepper.seconds),
            precision=run.stepper.precision,
            notes=notes,
        )

    def surrogate(
        self,
        history: np.ndarray,
        times: np.ndarray | None = None,
        *,
        scene: Scene | None = None,
        correction: bool = True,
        contact_distance: float = 1.0,
        link: int | None = None,
        precision: str | None = None,
    ):
        """A ``Surrogate`` started from ``history`` (arguments as
        ``rollout``): advance it frame by frame from your own code, read its state, hand
        a state back, read its timings."""
        from gripdem.api.coupling import Surrogate

        scene = self.scene if scene is None else scene
        observed, obs_times, single = self._history(history, times, scene)
        notes = self.check_scene(scene, observed.shape[2])
        settings = self._settings(correction, contact_distance, link, precision)
        return Surrogate(self.module(scene), scene, observed, obs_times, settings, single, notes)
