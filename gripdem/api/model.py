"""A trained model from Python: load it, roll it out, or step it inside your own code.

torch and the model code are imported by ``load_model``, not before.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gripdem.api.rollout_result import RolloutResult
from gripdem.api.scene import Scene
from gripdem.api.trajectory import check_frames
from gripdem.errors import RolloutDiverged

if TYPE_CHECKING:
    import torch

    from gripdem.api.coupling import Surrogate

TRAINING = "training"
"""``scene=gripdem.TRAINING`` (the string ``"training"``) applies a model in the scene it was
trained on: ``Model.rollout`` and ``Model.surrogate`` take it where they take the data's
``Scene``, so that applying a model in its training scene is said explicitly.

Examples:
    Data of the shipped Lees-Edwards model's training scene (its box holds 2000 particles at
    the scene's volume fraction), rolled out in that scene:

    >>> import gripdem
    >>> model = gripdem.load_model("pretrained:lebc")
    >>> data = gripdem.generate("lebc", "tiny", sims=1, particles=2000, frames=11)
    >>> data.scene.matches(model.scene)
    True
    >>> result = model.rollout(data.positions[0], data.times[0], frames=2, scene=gripdem.TRAINING)
    >>> result.scene == model.scene, result.notes
    (True, [])
"""
#: the release from which ``Model.rollout`` and ``Model.surrogate`` require ``scene`` (until
#: then, omitting it applied the training scene with a ``DeprecationWarning``)
SCENE_REQUIRED_FROM = "0.2.0"


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

    Examples:
        The shipped Lees-Edwards model and a small sheared scene of the built-in DEM to apply
        it to; the examples of the methods below use this ``model`` and this ``data``:

        >>> import gripdem
        >>> model = gripdem.load_model("pretrained:lebc")
        >>> data = gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)
        >>> model.history_len, model.horizon, model.is_ensemble
        (10, 10, False)

        It reads the last ``history_len + 1`` frames and predicts the next ones:

        >>> history, times = data.positions[0, :11], data.times[0, :11]
        >>> result = model.rollout(history, times, frames=10, scene=data.scene)
        >>> result.predicted.shape
        (10, 300, 3)
    """

    def __init__(self, source, path, hparams, state, card, device="cpu", precision="auto"):
        self.source, self.path = source, Path(path)
        self.hparams, self.card = dict(hparams), card
        self._state = state
        self.device, self.precision = str(device), str(precision)
        self.history_len = int(hparams["history_len"])
        self.horizon = int(hparams["horizon"])
        self.scene = Scene._from_model_scene(hparams["scene"])
        self._modules: dict[Scene, Any] = {}
        self._notes: dict[tuple[Scene, int], list[str]] = {}
        self.is_ensemble = bool(self.module(self.scene).is_ensemble)

    def __repr__(self) -> str:
        return (
            f"Model({self.source!r}: {self.hparams.get('encoding')} encoding, history "
            f"{self.history_len}, horizon {self.horizon}, {self.scene.boundary}, "
            f"{'ensemble' if self.is_ensemble else 'deterministic'})"
        )

    def module(self, scene: Scene | None = None) -> torch.nn.Module:
        """Advanced: the ``torch.nn.Module`` (a Lightning module) applied in ``scene``
        (default: the training scene), on the model's device, in eval mode.

        Built once per scene and kept: ``rollout`` and ``surrogate`` use the same module.

        Args:
            scene: the scene it is applied in (default: the training scene).

        Returns:
            the ``torch.nn.Module``, in eval mode.

        Raises:
            CheckpointError: the file's tensors do not fit its hyperparameters.

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> module = model.module(data.scene)
            >>> module.training
            False
            >>> sum(weight.numel() for weight in module.parameters())
            78364
        """
        scene = self.scene if scene is None else scene
        if scene not in self._modules:
            from gripdem.inference.checkpoint import build_module, data_scene

            meta = scene._to_meta(1, self.history_len + 1, 1)
            built = build_module(self.path, self.hparams, self._state, scene=data_scene(meta))
            self._modules[scene] = built.to(self.device).eval()
        return self._modules[scene]

    def check_scene(self, scene: Scene, particles: int) -> list[str]:
        """Notes on how ``scene`` differs from the training scene (the rule of
        ``docs/reference/rules.md``, as ``gripdem.predict`` applies it).

        ``rollout`` and ``surrogate`` call it; call it yourself to know beforehand whether
        a scene is accepted.

        Args:
            scene: the scene the model would be applied in.
            particles: particles per frame there.

        Returns:
            the notes, one string per difference within what the model accepts (empty in
            the training scene); ``RolloutResult.notes`` repeats them.

        Raises:
            IncompatibleError: the model cannot be applied there (named field, both values).

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``). This model reads relative geometry only, so
            it is applied in the smaller box, with a note:

            >>> model.check_scene(model.scene, particles=2000)
            []
            >>> print(model.check_scene(data.scene, data.n_particles)[0])
            box: data 1.6995e-05 vs model 3.1986e-05 (-46.9 %), beyond the 1 % tolerance,
            applied in the data's box: this model reads relative geometry only

            Another boundary is refused:

            >>> model.check_scene(data.scene.with_(boundary="periodic", shear_rate=0.0), 300)
            Traceback (most recent call last):
                ...
            gripdem.errors.IncompatibleError: <scene in memory>: field 'boundary': ...
        """
        from gripdem.inference.checkpoint import check_compatible

        key = (scene, int(particles))
        if key not in self._notes:  # the model file is read once per scene, not per call
            meta = scene._to_meta(1, self.history_len + 1, particles, path="<scene in memory>")
            self._notes[key] = check_compatible(self.path, meta)[1]
        return list(self._notes[key])

    def _scene(self, scene: Scene | str | None, method: str) -> Scene:
        """The scene a call applies the model in: a ``Scene``, or ``"training"``."""
        if scene is None:
            raise ValueError(
                f"Model.{method}() needs scene= (required since gripdem {SCENE_REQUIRED_FROM}): "
                "the data's scene (scene=trajectory.scene) or scene='training' for the model's "
                "training scene"
            )
        if isinstance(scene, str):
            if scene != TRAINING:
                raise ValueError(f"scene: expected a Scene or {TRAINING!r}, got {scene!r}")
            return self.scene
        if not isinstance(scene, Scene):
            raise ValueError(
                f"scene: expected a gripdem Scene or {TRAINING!r}, got {type(scene).__name__}"
            )
        return scene

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
        scene: Scene | str | None = None,
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
            scene: where it is applied: the data's ``Scene`` (``trajectory.scene``), or
                ``"training"`` for the model's training scene. Required (since 0.2.0;
                omitting it raises ``ValueError``).
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

        Raises:
            ValueError: a history, times, ``frames``, ``members`` or ``scene`` that is not
                as described (the argument named).
            IncompatibleError: a scene the model cannot be applied in (field named).
            RolloutDiverged: the model predicted NaN/Inf; its ``partial`` is the
                ``RolloutResult`` of the frames before (``Surrogate.advance`` raises the same).

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``). Predict the 10 frames after the first 11
            and score them against the DEM's:

            >>> history, times = data.positions[0, :11], data.times[0, :11]
            >>> result = model.rollout(history, times, frames=10, scene=data.scene)
            >>> result.positions.shape, result.n_observed, result.n_predicted
            ((21, 300, 3), 11, 10)
            >>> result.error(data.positions[0, 11:]).ratio_to_constant_velocity < 1
            True

            Several simulations at once keep their leading axis; an ensemble model draws
            ``members`` samples of each (a members axis follows):

            >>> model.rollout(data.positions[:, :11], data.times[:, :11], frames=3,
            ...               scene=data.scene).positions.shape
            (1, 14, 300, 3)
            >>> ensemble = gripdem.load_model("pretrained:lebc-ensemble")
            >>> ensemble.rollout(history, times, frames=3, scene=data.scene, members=4,
            ...                  seed=0).positions.shape
            (4, 14, 300, 3)

            The history is checked before anything is predicted:

            >>> model.rollout(history[:5], times[:5], scene=data.scene)
            Traceback (most recent call last):
                ...
            ValueError: history: expected (frames >= 11, particles, 3) or (sims, frames,
            particles, 3) positions (the model reads 11 frames), got (5, 300, 3)
        """
        from gripdem.inference.rollout import OVERLAP_MARGIN, rollout

        scene = self._scene(scene, "rollout")
        observed, obs_times, single = check_frames(
            "history", history, times, scene, self.history_len + 1
        )
        notes = self.check_scene(scene, observed.shape[2])
        meta = scene._to_meta(len(observed), observed.shape[1], observed.shape[2])
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
        result = RolloutResult(
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
            model=str(self.source),
        )
        if div.stopped is not None:
            raise RolloutDiverged(
                f"the model stopped: {div.stopped}; {result.n_predicted} of {frames} frames "
                "were predicted (the exception's .partial holds them)",
                partial=result,
            )
        return result

    def surrogate(
        self,
        history: np.ndarray,
        times: np.ndarray | None = None,
        *,
        scene: Scene | str | None = None,
        correction: bool = True,
        contact_distance: float = 1.0,
        link: int | None = None,
        precision: str | None = None,
    ) -> Surrogate:
        """A ``Surrogate`` started from ``history`` (arguments as
        ``rollout``): advance it frame by frame from your own code, read its state, hand
        a state back, read its timings.

        Args:
            history: positions ``(frames, N, 3)`` of one simulation or ``(S, frames, N, 3)``,
                wrapped, m; the last ``K + 1`` frames are read.
            times: absolute times ``(frames,)`` or ``(S, frames)``; default
                ``scene.times(frames)`` (0, dt, 2 dt, ...).
            scene: the data's ``Scene``, or ``"training"`` (``gripdem.TRAINING``) for the
                model's training scene; omitting it warns as in ``rollout``.
            correction: push overlapping particles apart after every frame.
            contact_distance: the closest centre distance the correction allows, in d.
            link: predicted frames kept per forward pass (default the horizon).
            precision: of the encoder (default the model's, ``load_model``).

        Returns:
            a ``Surrogate`` holding the last ``K + 1`` frames; nothing is predicted yet.

        Raises:
            ValueError: a history, times or ``scene`` that is not as described.
            IncompatibleError: a scene the model cannot be applied in (field named).

        Examples:
            ``model`` and ``data`` are those of the ``Model`` example
            (``gripdem.load_model("pretrained:lebc")`` and ``gripdem.generate("lebc", "tiny",
            sims=1, particles=300, frames=21)``):

            >>> surrogate = model.surrogate(data.positions[0, :11], data.times[0, :11],
            ...                             scene=data.scene)
            >>> surrogate.advance(3).shape
            (3, 300, 3)
            >>> surrogate.frames_advanced
            3
        """
        from gripdem.api.coupling import Surrogate

        scene = self._scene(scene, "surrogate")
        observed, obs_times, single = check_frames(
            "history", history, times, scene, self.history_len + 1
        )
        notes = self.check_scene(scene, observed.shape[2])
        settings = self._settings(correction, contact_distance, link, precision)
        return Surrogate(self.module(scene), scene, observed, obs_times, settings, single, notes)
