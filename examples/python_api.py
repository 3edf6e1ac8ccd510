"""From Python: generate a sheared scene with the built-in DEM, roll the shipped model out from
its first frames, and compare it with the DEM and with constant velocity, frame by frame and by
its physics.

    python examples/python_api.py [--frames 40] [--preset tiny|default]

``tiny`` (400 particles, 61 frames) runs in seconds; ``default`` is the scene the shipped model
was trained on (2000 particles, 201 frames; a few minutes of DEM).
"""

from __future__ import annotations

import argparse

import numpy as np

import gripdem
from gripdem.boundary import displacement  # the LE-aware minimum image (gripdem's conventions)


def rmse_over_d(predicted, truth, scene: gripdem.Scene, times) -> np.ndarray:
    """Per frame ``(frames,)``: RMSE of positions ``(frames, N, 3)`` in diameters."""
    box = scene.to_boundary().box
    error = displacement(predicted, truth, box, scene.offsets(times)[:, None])
    return np.sqrt((error**2).sum(-1).mean(-1)) / scene.diameter


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--preset", default="tiny")
    args = parser.parse_args(argv)

    # 1. a scene with the built-in DEM: arrays in memory, (sims, frames, particles, 3)
    data = gripdem.generate("lebc", preset=args.preset, sims=1, seed=7)
    print(f"DEM: {data.positions.shape} positions, scene {data.scene}")

    # 2. the shipped model, applied in this scene (it reads relative geometry only)
    model = gripdem.load_model("pretrained:lebc")
    k1 = model.history_len + 1
    frames = min(args.frames, data.n_frames - k1)
    history, times = data.positions[0, :k1], data.times[0, :k1]
    run = model.rollout(history, times, frames=frames, scene=data.scene)
    print(f"{model}: {run.n_predicted} frames in {sum(run.timings.values()):.2f} s")
    for note in run.notes:
        print(f"note: {note}")

    # 3. out of sample, beside constant velocity (the last observed step, repeated)
    truth = data.positions[0, k1 : k1 + frames]
    future = data.times[0, k1 : k1 + frames]
    box, offsets = data.scene.to_boundary().box, data.scene.offsets(data.times[0])
    step = displacement(history[-1], history[-2], box, offsets[k1 - 1])
    cv = np.stack([history[-1] + (j + 1) * step for j in range(frames)])
    model_error = rmse_over_d(run.predicted, truth, data.scene, future)
    cv_error = rmse_over_d(cv, truth, data.scene, future)
    print("frame   model RMSE/d   constant velocity RMSE/d")
    for j in sorted({0, 9, frames - 1}):
        print(f"{j + 1:5d}   {model_error[j]:12.4g}   {cv_error[j]:12.4g}")

    # 4. the physics of the rollout beside the DEM's over the same frames
    dem = gripdem.Trajectory(
        data.positions[0, k1 - 1 : k1 + frames], data.times[0, k1 - 1 : k1 + frames], data.scene
    )
    ours = gripdem.Trajectory(run.positions[k1 - 1 :], run.times[k1 - 1 :], data.scene)
    for name, trajectory in (("DEM", dem), ("model", ours)):
        report = gripdem.physics(trajectory, lags=[1, 10])
        print(
            f"{name:5s}: coordination {report.coordination:.2f}, overlaps "
            f"{report.overlap_fraction:.4f}, shear rate {report.profile[0]:.0f} 1/s, "
            f"non-affine MSD at lag 10 {report.non_affine_msd_over_d2[1]:.3g} d²"
        )


if __name__ == "__main__":
    main()
