"""A trained model from Python: load it, roll it out, or step it inside your own code.

torch and the model code are imported by ``load_model``, not before.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from gripdem.api.rollout_result import RolloutResult
from gripdem.api.scene import Scene, check_frames
from gripdem.errors import RolloutDiverged

#: ``scene=TRAINING`` applies a model in the scene it was trained on (say so explicitly)
TRAINING = "training"
#: the release from which ``Model.rollout`` and ``Model.surrogate`` require ``scene``
SCENE_REQUIRED_FROM = "0.2.0"


def load_model(source: str | os.PathLike, device: str = "cpu", precision: str = "auto") -> Model:
    """Load a trained model: ``"pretrained:pbc"``, ``"pretrained:lebc"``, a run's
    ``checkpoints/best.safetensors`` or a Lightning ``.ckpt``.

    Files are read as data (safetensors with a JSON card; nothing is unpickled). ``device``:
    a torch device (``"cpu"``, ``"cuda"``). ``precision``: of the encoder, ``"auto"`` (the
    default of ``gripdem.predict``: bf16 where the device computes it natively, CPU
    avx512_bf16/AMX or CUDA 8.0+, else fp32), ``"fp32"`` or ``"bf16"``.

    Raises:
        FileNotFoundError: no such file, or no shipped model of that ``pretrained:`` name.
        CheckpointError: the file is not a gripdem model, its tensors do not fit its
            hyperparameters, or it would run code when loaded (nothing in it is run).
        ValueError: a ``precision`` that is not one of the above (when it is first used)."""
    from gripdem.inference.checkpoint import read_checkpoint
    from gripdem.inference.pretrained import resolve

    path = resolve(source)
    hparams, state, card = read_checkpoint(path)
    return Model(str(source), path, hparams, state, dict(card), device, precision)


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

    def module(self, scene: Scene | None = None):
        """Advanced: the ``torch.nn.Module`` (a Lightning module) applied in ``scene``
        (default: the training scene), on the model's device, in eval mode.

        Raises:
            CheckpointError: the file's tensors do not fit its hyperparameters."""
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

        Raises:
            IncompatibleError: the model cannot be applied there (named field, both values)."""
        from gripdem.inference.checkpoint import check_compatible

        key = (scene, int(particles))
        if key not in self._notes:  # the model file is read once per scene, not per call
            meta = scene._to_meta(1, self.history_len + 1, particles, path="<scene in memory>")
            self._notes[key] = check_compatible(self.path, meta)[1]
        return list(self._notes[key])

    def _scene(self, scene: Scene | str | None, method: str) -> Scene:
        """The scene a call applies the model in: a ``Scene``, or ``"training"``."""
        if scene is None:
            warnings.warn(
                f"Model.{method}() without scene= applies the model in its training scene; "
                "pass the data's scene (scene=trajectory.scene) or scene='training' (scene "
                f"is required from gripdem {SCENE_REQUIRED_FROM})",
                DeprecationWarning,
                stacklevel=3,
            )
            return self.scene
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
                ``"training"`` for the model's training scene. Omitting it still means the
                training scene, with a ``DeprecationWarning`` (required from 0.2.0).
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
    ):
        """A ``Surrogate`` started from ``history`` (arguments as
        ``rollout``): advance it frame by frame from your own code, read its state, hand
        a state back, read its timings.

        Raises:
            ValueError: a history, times or ``scene`` that is not as described.
            IncompatibleError: a scene the model cannot be applied in (field named)."""
        from gripdem.api.coupling import Surrogate

        scene = self._scene(scene, "surrogate")
        observed, obs_times, single = check_frames(
            "history", history, times, scene, self.history_len + 1
        )
        notes = self.check_scene(scene, observed.shape[2])
        settings = self._settings(correction, contact_distance, link, precision)
        return Surrogate(self.module(scene), scene, observed, obs_times, settings, single, notes)
