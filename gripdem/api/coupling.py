"""A model stepped from your own code: advance, read the state, hand a state back.

The surrogate holds the model's state in memory (the last ``K + 1`` frames, their times and a
neighbour list with a skin): ``Surrogate.advance`` predicts frames on demand, one forward
pass per ``link`` frames, so asking for frames one at a time costs nothing extra. A coupled code
(a DEM engine that takes over, a fluid solver that moves the particles) reads
``Surrogate.state``, changes it, and hands it back with ``Surrogate.set_state``.
"""

from __future__ import annotations

import numpy as np

from gripdem.api.scene import Scene
from gripdem.api.trajectory import Trajectory, check_frames
from gripdem.errors import RolloutDiverged


class Surrogate:
    """The model advanced in memory (from ``gripdem.api.Model.surrogate``).

    Shapes follow the history it was started from: ``(frames, N, 3)`` for one simulation,
    ``(S, frames, N, 3)`` for ``S`` simulations stepped together.

    Examples:
        Start the shipped Lees-Edwards model from the first 11 frames of a small sheared
        scene of the built-in DEM, and advance it three frames at a time, as a coupled code
        would (the examples of the members below start from the same ``model`` and ``data``):

        >>> import gripdem
        >>> model = gripdem.load_model("pretrained:lebc")
        >>> data = gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)
        >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
        ...                             scene=data.scene)
        >>> for _ in range(3):
        ...     frames = surrogate.advance(3)
        >>> frames.shape, surrogate.frames_advanced, surrogate.positions.shape
        ((3, 300, 3), 9, (300, 3))
        >>> round(float(surrogate.time - data.times[0, 10]) / data.scene.frame_interval, 6)
        9.0
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

        Args:
            frames: how many frames to predict.

        Returns:
            the new frames, wrapped, m; the newest is ``positions``.

        Raises:
            ValueError: ``frames`` below 1.
            RolloutDiverged: the model predicted NaN/Inf (as ``Model.rollout`` raises): its
                ``partial`` holds the finite frames predicted before, nothing after them is
                kept; hand a state back with ``set_state`` to go on.

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> surrogate.advance(4).shape
            (4, 300, 3)
            >>> surrogate.advance(0)
            Traceback (most recent call last):
                ...
            ValueError: frames: expected a positive number of frames, got 0
        """
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
        """The newest frame: ``(N, 3)`` or ``(S, N, 3)``, wrapped, m.

        Returns:
            a copy of the newest frame (the last observed one before any ``advance``).

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> bool((surrogate.positions == data.positions[0, 10]).all())
            True
            >>> frames = surrogate.advance(2)
            >>> bool((surrogate.positions == frames[-1]).all())
            True
        """
        return self._out(self._stepper.frames[:, -1]).copy()

    @property
    def time(self) -> float | np.ndarray:
        """The newest frame's time (s): a float, or ``(S,)``.

        Returns:
            the absolute time of ``positions``, s.

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> surrogate.time == float(data.times[0, 10])
            True
            >>> _ = surrogate.advance(2)
            >>> round(float(surrogate.time - data.times[0, 10]) / data.scene.frame_interval, 6)
            2.0
        """
        now = self._stepper.times[:, -1]
        return float(now[0]) if self._single else now.copy()

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(frames, times)``: the ``K + 1`` frames the next prediction reads,
        ``(K+1, N, 3)`` and ``(K+1,)`` (or with a leading ``S``), copies.

        Returns:
            the tuple ``(frames, times)``: change them and hand them back with
            ``set_state``.

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> frames, times = surrogate.state
            >>> frames.shape, times.shape
            ((11, 300, 3), (11,))
        """
        return (
            self._out(self._stepper.frames).copy(),
            self._out(self._stepper.times).copy(),
        )

    def set_state(self, frames: np.ndarray, times: np.ndarray | None = None) -> None:
        """Hand a state back: go on from ``frames`` (``(>= K+1, N, 3)`` or with a leading
        ``S``; the last ``K + 1`` are read) at ``times`` (default: the current state's times).
        A link in progress is dropped and the neighbour lists are rebuilt; timings keep
        accumulating. The state is checked as ``Model.rollout`` checks a history.

        Args:
            frames: ``(>= K+1, N, 3)``, or ``(S, >= K+1, N, 3)`` for a surrogate of ``S``
                simulations, wrapped, m.
            times: their absolute times, s (default: the current state's).

        Raises:
            ValueError: frames of another shape, simulation count or particle count than
                the surrogate's, NaN/Inf, or times not one frame interval apart.

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``). Hand the DEM's frames 5 to 15 back, as a coupled
            code would after running the DEM itself:

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> _ = surrogate.advance(3)
            >>> surrogate.set_state(data.positions[0, 5:16], data.times[0, 5:16])
            >>> surrogate.time == float(data.times[0, 15])
            True
            >>> surrogate.set_state(data.positions[0, 5:16, :100])
            Traceback (most recent call last):
                ...
            ValueError: set_state: expected 300 particles (the surrogate's), got 100
        """
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
        """Frames predicted so far.

        Returns:
            the frames ``advance`` returned since the surrogate was made (``set_state``
            does not reset it).

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> _ = surrogate.advance(2)
            >>> _ = surrogate.advance(3)
            >>> surrogate.frames_advanced
            5
        """
        return self._stepper.n_predicted

    @property
    def timings(self) -> dict[str, float]:
        """Seconds spent so far per part: neighbour_list, features, forward, decode_wrap,
        correction, relaxation.

        Returns:
            a dict from part to seconds (a copy).

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> _ = surrogate.advance(3)
            >>> list(surrogate.timings)
            ['neighbour_list', 'features', 'forward', 'decode_wrap', 'correction', 'relaxation']
            >>> surrogate.timings["forward"] > 0
            True
        """
        return dict(self._stepper.seconds)

    @property
    def correction(self) -> dict[str, list]:
        """Per predicted frame: the contact correction's counts (overlapping pairs before and
        after, worst overlap before, RMS push in d), summed over the simulations.

        Returns:
            a dict from count to a list with one value per predicted frame (empty lists
            without correction).

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> _ = surrogate.advance(3)
            >>> surrogate.correction["overlapping_after"]
            [0, 0, 0]
            >>> len(surrogate.correction["worst_overlap_before"])
            3
        """
        return {k: list(v) for k, v in self._stepper.report.__dict__.items()}

    @property
    def precision(self) -> str:
        """The encoder's arithmetic (fp32 or bf16).

        Returns:
            ``"fp32"`` or ``"bf16"``: what ``precision="auto"`` chose on this device, or
            what was asked.

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> surrogate.precision in ("fp32", "bf16")
            True
            >>> model.surrogate(data.positions[0, :11], data.times[0, :11], scene=data.scene,
            ...                 precision="fp32").precision
            'fp32'
        """
        return self._stepper.precision

    def trajectory(self, frames: np.ndarray, times: np.ndarray) -> Trajectory:
        """Frames you collected from ``advance`` as a ``Trajectory`` of this scene.

        Args:
            frames: ``(frames, N, 3)`` or ``(S, frames, N, 3)``, wrapped, m.
            times: their absolute times, ``(frames,)`` or ``(S, frames)``, s.

        Returns:
            a ``Trajectory`` in the surrogate's scene, to write with
            ``gripdem.write_trajectory`` or to report with ``gripdem.physics``.

        Raises:
            ValueError: frames and times whose shapes do not match.

        Examples:
            ``model`` and ``data`` are those of the ``Surrogate`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``). Collect frames and their times, one at a time:

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> import numpy as np
            >>> frames, times = [], []
            >>> for _ in range(4):
            ...     frames.append(surrogate.advance(1)[0])
            ...     times.append(surrogate.time)
            >>> trajectory = surrogate.trajectory(np.stack(frames), np.array(times))
            >>> trajectory.positions.shape
            (1, 4, 300, 3)
        """
        return Trajectory(frames, times, self.scene, provenance={"generator": "gripdem.api"})
