"""The physics figure of a run: truth, model and every baseline side by side, from a
:class:`~gripdem.evaluation.physics_report.PhysicsReport` (four panels: z-velocity profile, g(r) at
the last predicted step, non-affine MSD over the horizon, distribution of the non-affine z
displacement at the last step).
Agg canvas only (:mod:`gripdem.plots.common`)."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from gripdem.evaluation.figure_data import BASELINE_LABELS
from gripdem.evaluation.physics_report import PhysicsReport
from gripdem.plots.common import new_figure

#: drawing order and styles: the truth and the model on top, baselines thinner
_STYLE = {"truth": {"color": "k", "lw": 2.6}, "model": {"color": "C3", "lw": 2.0}}


def _label(name: str, model_name: str) -> str:
    return model_name if name == "model" else BASELINE_LABELS.get(name, name)


def _styles(sets: list[str]) -> dict[str, dict]:
    styles, colour = {}, 0
    for name in sets:
        if name in _STYLE:
            styles[name] = _STYLE[name]
        else:
            styles[name] = {"color": f"C{colour}", "lw": 1.2, "ls": "--"}
            colour += 1
    return styles


def plot_physics(report: PhysicsReport, title: str, model_name: str = "model") -> Figure:
    """2 x 2 panels; each legend entry carries the set's scalar against the truth."""
    c, m = report.curves, report.metrics
    order = ["truth", "model"] + [s for s in report.sets if s not in ("truth", "model")]
    styles = _styles(order)
    fig = new_figure(11.0, 8.0)
    ax_profile, ax_gr, ax_msd, ax_na = (fig.add_subplot(2, 2, k) for k in range(1, 5))
    steps = np.arange(1, len(c["truth/msd"]) + 1)
    centres = 0.5 * (c["non_affine_edges"][1:] + c["non_affine_edges"][:-1])
    for name in order:
        style, label = styles[name], _label(name, model_name)
        err = m.get(f"{name}/profile_error_over_d")
        ax_profile.plot(
            c["profile_x"],
            c[f"{name}/profile"],
            label=label if err is None else f"{label} (RMS diff {err:.2g})",
            **style,
        )
        dist = m.get(f"{name}/gr_distance")
        coord = m[f"{name}/coordination_contact"]
        extra = f"Z {coord:.2f}" + ("" if dist is None else f", dist {dist:.3f}")
        ax_gr.plot(c["gr_r"], c[f"{name}/gr"], label=f"{label} ({extra})", **style)
        ax_msd.plot(steps, c[f"{name}/non_affine_msd"], label=label, **style)
        hist = c[f"{name}/non_affine_hist"].astype(float)
        rms = m[f"{name}/non_affine_rms_over_d"]
        ax_na.plot(
            centres, np.where(hist > 0, hist, np.nan), label=f"{label} (RMS {rms:.3g} d)", **style
        )
    ax_profile.set(xlabel="x / d", ylabel="mean v_z (d per frame)")
    ax_profile.set_title("z-velocity profile over the horizon", fontsize=9)
    ax_gr.set(xlabel="r / d", ylabel="g(r)", xlim=(0.8, c["gr_r"][-1]))
    ax_gr.set_title("g(r) at the last predicted step (Z: contacts, dist: L1 to truth)", fontsize=9)
    ax_msd.set(xlabel="horizon step", ylabel="non-affine MSD / d²", xscale="log", yscale="log")
    ax_msd.set_title("mean-squared displacement relative to the mean flow", fontsize=9)
    ax_na.set(xlabel="non-affine z displacement over the horizon / d", ylabel="count")
    ax_na.set_yscale("log")
    ax_na.set_title(f"relative to the mean flow ({report.profile_kind} profile fit)", fontsize=9)
    for ax in (ax_profile, ax_gr, ax_msd, ax_na):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"Physics of the predicted flow\n{title}", fontsize=10)
    return fig
