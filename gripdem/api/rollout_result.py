"""What a rollout returns: its frames and checks (``RolloutResult``), saved as a dataset or
scored against the truth beside constant velocity (``RolloutError``)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gripdem.api.scene import Scene
from gripdem.api.trajectory import Trajectory, write_trajectory


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
        model: what the model was loaded from.

    Examples:
        Roll the shipped Lees-Edwards model out over a small sheared scene of the built-in
        DEM: the 11 observed frames, then 10 predicted ones:

        >>> import gripdem
        >>> model = gripdem.load_model("pretrained:lebc")
        >>> data = gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)
        >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
        ...                        scene=data.scene)
        >>> result.positions.shape, result.times.shape, result.n_observed
        ((21, 300, 3), (21,), 11)
        >>> result.divergence["stopped"] is None  # it did not stop early
        True
        >>> result.correction["overlapping_after"]  # no overlap left after each correction
        [0, 0, 0, 0, 0, 0, 0, 0, 0, 0]
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
    model: str = ""

    @property
    def predicted(self) -> np.ndarray:
        """The predicted frames only: ``(*batch, n_predicted, N, 3)``.

        Returns:
            a view of ``positions`` after the ``n_observed`` observed frames.

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
            ...                        scene=data.scene)
            >>> result.predicted.shape
            (10, 300, 3)
            >>> bool((result.predicted == result.positions[11:]).all())
            True
        """
        return self.positions[..., self.n_observed :, :, :]

    @property
    def n_predicted(self) -> int:
        """Frames predicted (fewer than asked only in the ``partial`` of a
        ``RolloutDiverged``).

        Returns:
            the number of predicted frames.

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
            ...                        scene=data.scene)
            >>> result.n_predicted
            10
        """
        return self.positions.shape[-3] - self.n_observed

    @property
    def seconds_per_frame(self) -> float:
        """Wall time of the stepper per predicted frame (all simulations together).

        Returns:
            seconds per frame: the sum of ``timings`` over ``n_predicted``.

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
            ...                        scene=data.scene)
            >>> result.seconds_per_frame > 0
            True
            >>> sorted(result.timings)
            ['correction', 'decode_wrap', 'features', 'forward', 'neighbour_list', 'relaxation']
        """
        return sum(self.timings.values()) / max(self.n_predicted, 1)

    def trajectory(self) -> Trajectory:
        """The rollout as a ``Trajectory`` (rows: simulation-major, then members), to
        write with ``gripdem.write_trajectory`` or to report with ``gripdem.physics``. Raises
        nothing of its own.

        Returns:
            a ``Trajectory`` of the observed and predicted frames, one row per simulation and
            member; its provenance names the model and the observed frame count.

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
            ...                        scene=data.scene)
            >>> trajectory = result.trajectory()
            >>> trajectory.positions.shape, trajectory.provenance["observed_frames"]
            ((1, 21, 300, 3), 11)
            >>> gripdem.physics(trajectory).frames
            21
        """
        n, t = self.positions.shape[-2], self.positions.shape[-3]
        return Trajectory(
            self.positions.reshape(-1, t, n, 3),
            self.times.reshape(-1, t),
            self.scene,
            provenance={
                "generator": "gripdem.api",
                "model": self.model,
                "members": self.members,
                "observed_frames": self.n_observed,
                "notes": list(self.notes),
            },
        )

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the rollout (observed, then predicted frames) as a gripdem HDF5 dataset that
        every command reads (``gripdem.predict``, ``gripdem.physics_report``, training with
        ``data.path=``); its provenance names the model, the observed frame count and the
        notes. Validated first, written atomically; returns the path.

        Args:
            path: where to write (``.h5``).
            overwrite: replace an existing file.

        Returns:
            ``path`` as a ``pathlib.Path``.

        Raises:
            FileExistsError: ``path`` exists and ``overwrite`` is False (nothing written).
            DatasetError: the frames cannot form a valid dataset (named field).

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
            ...                        scene=data.scene)
            >>> path = result.save("rollout.h5")
            >>> back = gripdem.read_trajectory(path)
            >>> back.n_frames, back.provenance["model"]
            (21, 'pretrained:lebc')
        """
        return write_trajectory(path, self.trajectory(), overwrite=overwrite)

    def error(self, truth: np.ndarray) -> RolloutError:
        """The error of the predicted frames against ``truth`` and constant velocity's on the
        same frames (from the same observed history): LE-aware minimum image at each frame's
        own offset, in particle diameters (``docs/spec/evaluation.md#rmse``).

        Args:
            truth: the true positions of the predicted frames, shaped like ``predicted``
                without a members axis: ``(n_predicted, N, 3)`` or ``(S, n_predicted, N, 3)``
                (more frames are cut to ``n_predicted``), wrapped, m.

        Returns:
            a ``RolloutError``; for an ensemble, every member is scored against the truth
            and the errors pooled (a member's RMSE, not the ensemble mean's).

        Raises:
            ValueError: ``truth`` of another shape, or with NaN/Inf.

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
            ...                        scene=data.scene)
            >>> error = result.error(data.positions[0, 11:])
            >>> error.per_frame_over_d.shape
            (10,)
            >>> error.ratio_to_constant_velocity < 1  # better than constant velocity
            True
            >>> result.error(data.positions[0, 11:15])
            Traceback (most recent call last):
                ...
            ValueError: truth: expected (10, 300, 3) (the predicted frames), got (4, 300, 3)
        """
        from gripdem.evaluation.metrics import position_residuals, rmse_per_step
        from gripdem.models.baselines import constant_velocity

        batch = self.positions.shape[:-3]
        sims = batch[:-1] if self.members > 1 else batch  # the members axis comes last
        want = (*sims, self.n_predicted, *self.positions.shape[-2:])
        truth = np.asarray(truth, dtype=np.float64)
        if (
            truth.ndim != len(want)
            or truth.shape[:-3] != want[:-3]
            or truth.shape[-2:] != want[-2:]
            or truth.shape[-3] < self.n_predicted
        ):
            raise ValueError(f"truth: expected {want} (the predicted frames), got {truth.shape}")
        truth = truth[..., : self.n_predicted, :, :]
        if not np.isfinite(truth).all():
            raise ValueError("truth: positions must be finite (NaN or Inf found)")
        n, k1, f = self.positions.shape[-2], self.n_observed, self.n_predicted
        if self.members > 1:  # score each member: the truth repeated along the members axis
            truth = np.repeat(truth[..., None, :, :, :], self.members, axis=-4)
        predicted = self.predicted.reshape(-1, f, n, 3)
        truth = truth.reshape(-1, f, n, 3)
        times = self.times.reshape(-1, k1 + f)
        offsets = self.scene.offsets(times)
        box = self.scene.to_boundary().box
        model = position_residuals(predicted, truth, box, offsets[:, k1:])
        observed = self.positions.reshape(-1, k1 + f, n, 3)[:, :k1]
        cv = constant_velocity(observed, offsets[:, :k1], offsets[:, k1:], box).numpy()
        baseline = position_residuals(cv, truth, box, offsets[:, k1:])
        d = self.scene.diameter
        return RolloutError(rmse_per_step(model) / d, rmse_per_step(baseline) / d, self.members)


@dataclass
class RolloutError:
    """The error of a rollout against the truth (from ``RolloutResult.error``), in particle
    diameters, beside constant velocity's from the same observed frames.

    Attributes:
        per_frame_over_d: ``(n_predicted,)`` RMSE / d at each predicted frame.
        constant_velocity_per_frame_over_d: ``(n_predicted,)`` constant velocity's.
        members: ensemble members pooled (1: a deterministic rollout).

    Examples:
        Score a rollout of the shipped Lees-Edwards model over a small sheared scene of the
        built-in DEM against the DEM's own frames:

        >>> import gripdem
        >>> model = gripdem.load_model("pretrained:lebc")
        >>> data = gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)
        >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
        ...                        scene=data.scene)
        >>> error = result.error(data.positions[0, 11:])
        >>> error.per_frame_over_d.shape, error.members
        ((10,), 1)
        >>> bool((error.per_frame_over_d[1:] > error.per_frame_over_d[:-1]).all())  # it grows
        True
        >>> error.rmse_over_d < error.constant_velocity_rmse_over_d
        True
    """

    per_frame_over_d: np.ndarray
    constant_velocity_per_frame_over_d: np.ndarray
    members: int = 1

    @property
    def rmse_over_d(self) -> float:
        """RMSE / d over all predicted frames (root of the mean squared error).

        Returns:
            the RMSE in particle diameters.

        Examples:
            ``model`` and ``data`` are those of the ``RolloutError`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
            ...                        scene=data.scene)
            >>> error = result.error(data.positions[0, 11:])
            >>> 0 < error.rmse_over_d < 0.1  # a small fraction of a diameter
            True
        """
        return float(np.sqrt(np.mean(self.per_frame_over_d**2)))

    @property
    def constant_velocity_rmse_over_d(self) -> float:
        """Constant velocity's RMSE / d over the same frames.

        Returns:
            the RMSE in particle diameters of positions extrapolated at the last observed
            velocity.

        Examples:
            ``model`` and ``data`` are those of the ``RolloutError`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
            ...                        scene=data.scene)
            >>> error = result.error(data.positions[0, 11:])
            >>> error.constant_velocity_rmse_over_d > error.rmse_over_d
            True
        """
        return float(np.sqrt(np.mean(self.constant_velocity_per_frame_over_d**2)))

    @property
    def ratio_to_constant_velocity(self) -> float:
        """``rmse_over_d / constant_velocity_rmse_over_d``: below 1, the model beats it.

        Returns:
            the ratio of the two RMSEs.

        Examples:
            ``model`` and ``data`` are those of the ``RolloutError`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> result = model.rollout(data.positions[0, :11], data.times[0, :11], frames=10,
            ...                        scene=data.scene)
            >>> error = result.error(data.positions[0, 11:])
            >>> 0 < error.ratio_to_constant_velocity < 1
            True
        """
        return self.rmse_over_d / self.constant_velocity_rmse_over_d
