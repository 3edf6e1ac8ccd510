"""How much spin-up does the DEM's steady state need? The flow profile and the contact number of
simulations written from their first driven frame, against the plateau they settle on.

    python -m gripdem.simulate scene=SCENE preset.spinup_time=0.0 preset.frames=421 sims=2 \\
        seed=11 out=RUN/SCENE.h5 strict=false          # for pbc and lebc
    python experiments/analyses/spinup_plateau.py RUN/pbc.h5 RUN/lebc.h5 [--window 20]
        [--out experiments/results/dem_data/spinup_plateau]

Per frame and simulation: the mean-flow amplitude (pbc: the cosine's, ``2 <v_z cos(2 pi x /
lx)>``; lebc: the slope of ``v_z`` against ``x`` over the shear rate) and the contact number
(neighbours within 1.01 d per particle, Lees-Edwards images included). The plateau is each
statistic's mean over the frames that today's spin-up would have discarded up to and past (the
last half of the run); a statistic has settled at the first frame from which its running mean
over ``--window`` frames stays within the band ``plateau ± max(2 standard errors, 2 %)`` to the
end. The report gives that frame as time, frames and strain per scene, beside the preset's
spin-up, and a figure of both statistics against time.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from benchlib import markdown_table, write_report  # noqa: E402

from gripdem.boundary import neighbour_pairs  # noqa: E402
from gripdem.data.dataset_io import read_meta  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
#: contacts: neighbours within this many diameters
CONTACT = 1.01
#: the smallest band a settled statistic keeps to, relative to its plateau
MIN_BAND = 0.02


def flow_statistic(positions: np.ndarray, velocities: np.ndarray, meta) -> np.ndarray:
    """Per frame ``(T,)``: pbc, the cosine amplitude of ``v_z(x)`` (m/s); lebc, the slope of
    ``v_z`` against ``x`` over the imposed shear rate."""
    x, vz = positions[..., 0], velocities[..., 2]
    if meta.boundary.is_lees_edwards:
        xc = x - x.mean(axis=1, keepdims=True)
        slope = (xc * (vz - vz.mean(axis=1, keepdims=True))).sum(1) / (xc**2).sum(1)
        return slope / float(
            meta.boundary.lees_edwards.shear_rate * meta.boundary.lees_edwards.sign
        )
    return 2.0 * (vz * np.cos(2 * np.pi * x / meta.box.lx)).mean(axis=1)


def contact_number(positions: np.ndarray, times: np.ndarray, meta) -> np.ndarray:
    """Per frame ``(T,)``: neighbours within ``CONTACT`` d per particle."""
    out = np.empty(len(positions))
    for t, frame in enumerate(positions):
        offset = float(meta.boundary.offset(times[t])) if meta.boundary.is_lees_edwards else 0.0
        i, _, _ = neighbour_pairs(frame, meta.box, offset, CONTACT * meta.diameter)
        out[t] = 2.0 * len(i) / len(frame)  # each pair is listed once
    return out


def settled_frame(series: np.ndarray, window: int) -> tuple[int | None, float, float]:
    """``(first settled frame, plateau, band)`` of one statistic ``(T,)`` (see the module doc);
    the frame is None when the statistic is still outside its band at the run's end (it drifts)."""
    late = series[len(series) // 2 :]
    plateau = float(late.mean())
    band = max(2 * float(late.std(ddof=1)) / np.sqrt(window), MIN_BAND * abs(plateau))
    running = np.convolve(series, np.ones(window) / window, mode="valid")  # ends at t+window-1
    outside = np.nonzero(np.abs(running - plateau) > band)[0]
    if len(outside) and outside[-1] == len(running) - 1:
        return None, plateau, band
    first = int(outside[-1] + 1 + window - 1) if len(outside) else window - 1
    return first, plateau, band


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", type=Path, nargs="+")
    parser.add_argument("--window", type=int, default=20)
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments/results/dem_data/spinup_plateau"
    )
    args = parser.parse_args(argv)
    import yaml

    preset = yaml.safe_load((ROOT / "conf/preset/default.yaml").read_text())
    rows, data, curves = [], {}, {}
    for path in args.files:
        meta = read_meta(path)
        scene = "lebc" if meta.boundary.is_lees_edwards else "pbc"
        with h5py.File(path) as h5:
            positions = np.asarray(h5["positions"], np.float64)
            velocities = np.asarray(h5["velocities"], np.float64)
            times = np.asarray(h5["times"], np.float64)
        dt = float(times[0, 1] - times[0, 0])
        rate = (
            float(meta.boundary.lees_edwards.shear_rate * meta.boundary.lees_edwards.sign)
            if meta.boundary.is_lees_edwards
            else None
        )
        stats = {
            "flow": np.mean(
                [flow_statistic(p, v, meta) for p, v in zip(positions, velocities, strict=True)],
                axis=0,
            ),
            "contacts": np.mean(
                [contact_number(p, t, meta) for p, t in zip(positions, times, strict=True)], axis=0
            ),
        }
        curves[scene] = (times[0] - times[0, 0], stats)
        data[scene] = {"file": path.name, "sims": len(positions), "frames": positions.shape[1]}
        for name, series in stats.items():
            first, plateau, band = settled_frame(series, args.window)
            settle_time = None if first is None else first * dt
            if settle_time is None:
                cells = ["not within the run (it drifts)", "–", "–"]
            else:
                strain = f"{settle_time * rate:.2f}" if rate else "–"
                cells = [first, f"{settle_time * 1e3:.3f}", strain]
            rows.append([scene, name, f"{plateau:.4g} ± {band:.2g}", *cells])
            data[scene][name] = {
                "plateau": plateau,
                "band": band,
                "settled_frame": first,
                "settled_time_s": settle_time,
                "per_frame": series.tolist(),
            }
    spinup = float(preset["spinup_time"])
    text = (
        "# Spin-up: when the flow profile and the contact number settle\n\n"
        "Simulations written from their first driven frame "
        f"({', '.join(f.name for f in args.files)}; "
        "per frame, the mean over the simulations). A statistic has settled from the frame "
        f"after which its {args.window}-frame running mean stays within the band of its plateau "
        f"(the mean over the run's last half) to the end. The default preset's spin-up: "
        f"{spinup * 1e3:g} ms ({round(spinup / 5e-6)} frames of 5 µs; strain "
        f"{spinup * 1000:.2g} at 1000 1/s).\n\n"
        + markdown_table(
            ["scene", "statistic", "plateau ± band", "settled from frame", "time (ms)", "strain"],
            rows,
        )
    )
    write_report(args.out, text, data)
    figure = args.out.parent / f"{args.out.name}.png"
    from gripdem.plots.common import new_figure, save_figure

    fig = new_figure(5.0 * len(curves), 6.0)
    axes = np.asarray(fig.subplots(2, len(curves), squeeze=False))
    for col, (scene, (t, stats)) in enumerate(curves.items()):
        for row, name in enumerate(("flow", "contacts")):
            ax = axes[row, col]
            entry = data[scene][name]
            ax.plot(t * 1e3, stats[name], lw=1)
            ax.axhspan(
                entry["plateau"] - entry["band"], entry["plateau"] + entry["band"], alpha=0.2
            )
            if entry["settled_time_s"] is not None:
                ax.axvline(entry["settled_time_s"] * 1e3, color="C1", ls="--", label="settled")
            ax.axvline(spinup * 1e3, color="k", ls=":", label="default spin-up")
            ax.set_xlabel("time since the drive started (ms)")
            ax.set_ylabel(
                {
                    "flow": "flow: slope ÷ shear rate"
                    if scene == "lebc"
                    else "flow: cosine amplitude (m/s)",
                    "contacts": "contacts per particle (1.01 d)",
                }[name]
            )
            ax.set_title(f"{scene}: {name}")
            ax.legend(fontsize=8)
    save_figure(fig, figure)
    print(f"wrote {figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
