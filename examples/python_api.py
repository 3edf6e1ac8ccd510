"""From Python: generate a sheared scene with the built-in DEM, roll the shipped model out from
its first frames, and compare it with the DEM and with constant velocity, frame by frame and by
its physics.

    python examples/python_api.py [--frames 40] [--preset tiny|default]

``tiny`` (400 particles, 61 frames) runs in seconds; ``default`` is the scene the shipped model
was trained on (2000 particles, 201 frames; a few minutes of DEM).
"""

from __future__ import annotations

import argparse

import gripdem


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

    # 3. out of sample, beside constant velocity from the same observed frames (LE-aware
    #    minimum image, each frame with its own offset)
    error = run.error(data.positions[0, k1 : k1 + frames])
    print("frame   model RMSE/d   constant velocity RMSE/d")
    for j in sorted({0, 9, frames - 1}):
        model_error, cv_error = (
            error.per_frame_over_d[j],
            error.constant_velocity_per_frame_over_d[j],
        )
        print(f"{j + 1:5d}   {model_error:12.4g}   {cv_error:12.4g}")
    print(f"all frames: {error.ratio_to_constant_velocity:.3f} of constant velocity's RMSE")

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
