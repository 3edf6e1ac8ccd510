"""A model stepped from your own code: advance, read the state, hand a state back.

The surrogate holds the model's state in memory (the last ``K + 1`` frames, their times and a
neighbour list with a skin): ``Surrogate.advance`` predicts frames on demand, one forward
pass per ``link`` frames, so asking for frames one at a time costs nothing extra. A coupled code
(a DEM engine that takes over, a fluid solver that moves the particles) reads
``Surrogate.state``, changes it, and hands it back with ``Surrogate.set_state``.
"""

from __future__ import annotations

import numpy as np

from gripdem.api.scene import Scene, Trajectory, check_frames
from gripdem.errors import RolloutDiverged


class Surrogate:
    """The model advanced in memory (from ``gripdem.api.Model.surrogate``).

    Shapes follow the history it was started from: ``(frames, N, 3)`` for one simulation,
    ``(S, frames, N, 3)`` for ``S`` simulations stepped together.
    """

    def __init__(self, module, scene: Scene, observed, times, settings, single: bool, notes):
        from gripdem.inference.stepper import Stepper

        self.scene = scene
        self.notes = list(notes)
        self._single = single
        self._stepper = Stepper(module, observed, times, settings)

    def _out(self, array: np.ndarray) -> np.ndarray:
        return array[0] if self._single else array

    def advance(self, frames: int = 1) -> np.ndarray:
        """Predict ``frames`` more frames and return them ``(frames, N, 3)`` (one simulation)
        or ``(S, frames, N, 3)``, contact-corrected as kept.

        Raises:
            ValueError: ``frames`` below 1.
            RolloutDiverged: the model predicted NaN/Inf (as ``Model.rollout`` raises): its
                ``partial`` holds the finite frames predicted before, nothing after them is
                kept; hand a state back with ``set_state`` to go on."""
        frames = int(frames)
        if frames < 1:
            raise ValueError(f"frames: expected a positive number of frames, got {frames}")
        new = self._stepper.advance(frames)
        if self._stepper.stopped is not None:
            raise RolloutDiverged(
                f"the model stopped: {self._stepper.stopped}; {new.shape[1]} of {frames} "
                "frames were predicted (the exception's .partial holds them; hand a state "
                "back with set_state to go on)",
                partial=self._out(new),
            )
        return self._out(new)

    @property
    def positions(self) -> np.ndarray:
        """The newest frame: ``(N, 3)`` or ``(S, N, 3)``, wrapped, m."""
        return self._out(self._stepper.frames[:, -1]).copy()

    @property
    def time(self) -> float | np.ndarray:
        """The newest frame's time (s): a float, or ``(S,)``."""
        now = self._stepper.times[:, -1]
        return float(now[0]) if self._single else now.copy()

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(frames, times)``: the ``K + 1`` frames the next prediction reads,
        ``(K+1, N, 3)`` and ``(K+1,)`` (or with a leading ``S``), copies."""
        return (
            self._out(self._stepper.frames).copy(),
            self._out(self._stepper.times).copy(),
        )

    def set_state(self, frames: np.ndarray, times: np.ndarray | None = None) -> None:
        """Hand a state back: go on from ``frames`` (``(>= K+1, N, 3)`` or with a leading
        ``S``; the last ``K + 1`` are read) at ``times`` (default: the current state's times).
        A link in progress is dropped and the neighbour lists are rebuilt; timings keep
        accumulating. The state is checked as ``Model.rollout`` checks a history.

        Raises:
            ValueError: frames of another shape, simulation count or particle count than
                the surrogate's, NaN/Inf, or times not one frame interval apart."""
        k1 = self._stepper.k + 1
        sims, particles = self._stepper.frames.shape[0], self._stepper.frames.shape[2]
        frames = np.asarray(frames, dtype=np.float64)
        if frames.ndim != (3 if self._single else 4):
            raise ValueError(
                f"set_state: expected frames ({'' if self._single else 'sims, '}>= {k1}, "
                f"particles, 3), got {frames.shape}"
            )
        if times is None:
            times = self._out(self._stepper.times)
        checked, times, _ = check_frames("set_state", frames, times, self.scene, k1, particles)
        if checked.shape[0] != sims:
            raise ValueError(
                f"set_state: expected {sims} simulations (the surrogate's), got {checked.shape[0]}"
            )
        self._stepper.set_state(checked, times)

    @property
    def frames_advanced(self) -> int:
        """Frames predicted so far."""
        return self._stepper.n_predicted

    @property
    def timings(self) -> dict[str, float]:
        """Seconds spent so far per part: neighbour_list, features, forward, decode_wrap,
        correction, relaxation."""
        return dict(self._stepper.seconds)

    @property
    def correction(self) -> dict[str, list]:
        """Per predicted frame: the contact correction's counts (overlapping pairs before and
        after, worst overlap before, RMS push in d), summed over the simulations."""
        return {k: list(v) for k, v in self._stepper.report.__dict__.items()}

    @property
    def precision(self) -> str:
        """The encoder's arithmetic (fp32 or bf16)."""
        return self._stepper.precision

    def trajectory(self, frames: np.ndarray, times: np.ndarray) -> Trajectory:
        """Frames you collected from ``advance`` as a ``Trajectory`` of this scene.

        Raises:
            ValueError: frames and times whose shapes do not match."""
        return Trajectory(frames, times, self.scene, provenance={"generator": "gripdem.api"})
