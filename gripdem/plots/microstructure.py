"""The microstructure figure of an ensemble's long rollout, drawn from its computed report (one
scene of ``experiments/benchmarks/surrogate/surrogate_rollout.py --members M --reference ...``).

Three panels over the blocks of the rollout: contacts within 1.01 d, the g(r) L1 distance and
the non-affine MSD at lag 10, each model / truth (g(r): the distance itself). Every member with
block statistics is a thin line, the deterministic reference a black line; the grey band is
what "equal" means (two independent DEM simulations of the scene, the noise floor), the dashed
lines the targets.
"""

from __future__ import annotations

from matplotlib.figure import Figure

from gripdem.evaluation.rollout_stats import SURROGATE_TARGETS
from gripdem.plots.common import new_figure

#: (block key, panel title, target: ± ratio band or the largest distance)
PANELS = (
    ("ratio/coordination", "contacts within 1.01 d", SURROGATE_TARGETS["coordination"]),
    ("gr_l1", "g(r) L1 distance (0-3 d)", SURROGATE_TARGETS["gr_l1"]),
    ("ratio/msd_10_over_d2", "non-affine MSD, lag 10", SURROGATE_TARGETS["msd"]),
)


def _centres(blocks: list[dict]) -> list[float]:
    return [0.5 * (b["frames"][0] + b["frames"][1]) for b in blocks]


def plot_microstructure(entry: dict, reference: dict | None, title: str) -> Figure:
    """The three panels (see the module doc) of an ensemble ``entry`` beside the deterministic
    ``reference`` entry of the same report (None: members only)."""
    fig = new_figure(13.0, 3.9)
    axes = fig.subplots(1, 3)
    members = [entry["blocks"]["blocks"], *entry.get("member_blocks", [])]
    floor = entry.get("noise_floor", {}).get("blocks", [])
    for ax, (key, label, target) in zip(axes, PANELS, strict=True):
        distance = key == "gr_l1"
        if floor:
            spread = max(b[key] if distance else abs(b[key] - 1) for b in floor)
            low, high = (0.0, spread) if distance else (1 - spread, 1 + spread)
            ax.axhspan(low, high, color="0.85", label="two DEM runs (noise floor)")
        for line in [target] if distance else [1 - target, 1 + target]:
            ax.axhline(line, color="C1", ls="--", lw=1)
        target_label = f"target ≤ {target:g}" if distance else f"target ±{target:.0%}"
        ax.plot([], [], color="C1", ls="--", lw=1, label=target_label)
        for m, blocks in enumerate(members):
            ax.plot(
                _centres(blocks),
                [b[key] for b in blocks],
                color="C0",
                lw=0.9,
                alpha=0.8,
                label=f"ensemble members ({len(members)})" if m == 0 else None,
            )
        if reference is not None:
            blocks = reference["blocks"]["blocks"]
            ax.plot(
                _centres(blocks),
                [b[key] for b in blocks],
                color="k",
                marker="o",
                ms=3,
                label="deterministic model",
            )
        if not distance:
            ax.axhline(1.0, color="k", lw=0.6)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("predicted frame (block centre)")
        ax.set_ylabel("distance" if distance else "model / truth")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    return fig
