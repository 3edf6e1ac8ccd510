"""Couple the surrogate to your own code: step it frame by frame, and every ``--every`` frames
hand it a state from outside (here the DEM's own frames, as a data-assimilation loop would;
a fluid solver or a DEM engine that takes over would hand back its frames the same way).

    python examples/coupling.py [--frames 40] [--every 10]

Prints the error of the free-running surrogate beside the one that is handed the DEM's state,
and where the surrogate's time went (its per-part timings).
"""

from __future__ import annotations

import argparse

import numpy as np

import gripdem
from gripdem.boundary import displacement


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--every", type=int, default=10)
    args = parser.parse_args(argv)

    data = gripdem.generate("lebc", preset="tiny", sims=1, seed=7)
    model = gripdem.load_model("pretrained:lebc")
    k1 = model.history_len + 1
    positions, times = data.positions[0], data.times[0]
    frames = min(args.frames, data.n_frames - k1)
    box = data.scene.to_boundary().box

    def error_over_d(frame: np.ndarray, index: int) -> float:
        offset = data.scene.offsets(times[index])
        gap = displacement(frame, positions[index], box, offset)
        return float(np.sqrt((gap**2).sum(-1).mean()) / data.scene.diameter)

    free = model.surrogate(positions[:k1], times[:k1], scene=data.scene)
    coupled = model.surrogate(positions[:k1], times[:k1], scene=data.scene)
    print("frame   free-running RMSE/d   handed the DEM state every", args.every)
    for index in range(k1, k1 + frames):
        free_frame = free.advance(1)[0]  # (N, 3): one frame at a time costs nothing extra
        coupled_frame = coupled.advance(1)[0]
        done = index - k1 + 1
        if done % args.every == 0 or done == frames:
            print(
                f"{done:5d}   {error_over_d(free_frame, index):19.4g}   "
                f"{error_over_d(coupled_frame, index):.4g}"
            )
        if done % args.every == 0:  # your code's state goes back in: the last K + 1 frames
            coupled.set_state(
                positions[index - k1 + 1 : index + 1], times[index - k1 + 1 : index + 1]
            )
    state_frames, state_times = coupled.state
    print(f"state: {state_frames.shape} frames up to t = {state_times[-1]:.6g} s")
    total = sum(free.timings.values())
    parts = ", ".join(f"{k} {v / total:.0%}" for k, v in free.timings.items() if v > 0)
    print(
        f"free-running: {1e3 * total / free.frames_advanced:.2f} ms per frame ({parts}), "
        f"precision {free.precision}"
    )


if __name__ == "__main__":
    main()
