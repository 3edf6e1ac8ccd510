"""Markdown tables of ``surrogate_rollout.py`` (a sibling module of the script): speed, short-term
RMSE, per-block statistics beside the noise floor, hand-back, and every target met or missed."""

from __future__ import annotations

import math

import numpy as np
from benchlib import fmt, markdown_table

MARKS = (1, 10, 30, 100)


def _worst(blocks, key, target=1.0) -> float:
    """Largest |value - target| over the blocks (NaN ignored)."""
    values = [abs(b[key] - target) for b in blocks if not math.isnan(b.get(key, math.nan))]
    return max(values) if values else math.nan


def targets(scene: dict) -> list[list]:
    blocks = scene["blocks"]["blocks"]
    model_overlap = max(scene["blocks"]["overlap_per_frame"]["model"])
    rm = scene["rmse_over_d"]
    n = len(rm["model"])
    losses = sum(
        1 for j in range(n) if rm["model"][j] > min(rm["constant_velocity"][j], rm["linear_ar"][j])
    )
    drift = max(abs(b["model/drift_over_d"]) for b in blocks)
    truth_drift = max(abs(b["truth/drift_over_d"]) for b in blocks)
    ratios = [h.get("fluctuation_ratio", math.inf) for h in scene["handback"]]
    rows = [
        ["overlap <= 1 % every frame", fmt(100 * model_overlap) + " %", model_overlap <= 0.01],
        [
            "g(r) L1 <= 0.02 every block",
            fmt(max(b["gr_l1"] for b in blocks)),
            max(b["gr_l1"] for b in blocks) <= 0.02,
        ],
        [
            "coordination within 2 %",
            fmt(_worst(blocks, "ratio/coordination")),
            _worst(blocks, "ratio/coordination") <= 0.02,
        ],
        [
            "profile within 3 %",
            fmt(_worst(blocks, "ratio/profile")),
            _worst(blocks, "ratio/profile") <= 0.03,
        ],
        [
            "drift within the truth's noise (~1e-4 d / frame)",
            f"{drift:.2g} (truth {truth_drift:.2g})",
            drift <= max(1e-4, 2 * truth_drift),
        ],
        [
            "non-affine MSD lag 10 within 15 %",
            fmt(_worst(blocks, "ratio/msd_10_over_d2")),
            _worst(blocks, "ratio/msd_10_over_d2") <= 0.15,
        ],
        [
            "non-affine MSD lag 100 within 15 %",
            fmt(_worst(blocks, "ratio/msd_100_over_d2")),
            _worst(blocks, "ratio/msd_100_over_d2") <= 0.15,
        ],
        [
            "RMS step within 10 %",
            fmt(_worst(blocks, "ratio/rms_step_over_d")),
            _worst(blocks, "ratio/rms_step_over_d") <= 0.10,
        ],
        [
            "hand-back KE ratio <= 2",
            ", ".join(fmt(r) for r in ratios),
            bool(ratios) and max(ratios) <= 2,
        ],
        [f"RMSE <= CV and AR, frames 1-{n}", f"{losses} frame(s) above", losses == 0],
        ["50x faster than the DEM per frame", fmt(scene["speedup"]) + "x", scene["speedup"] >= 50],
    ]
    return [[name, value, "met" if ok else "MISSED"] for name, value, ok in rows]


def block_table(scene: dict) -> str:
    rows = []
    for b in scene["blocks"]["blocks"]:
        rows.append(
            [
                f"{b['frames'][0]}-{b['frames'][1]}",
                f"{100 * b['model/overlap_max']:.2f} / {100 * b['truth/overlap_max']:.2f}",
                fmt(b["gr_l1"]),
                fmt(b["ratio/coordination"]),
                fmt(b["ratio/profile"]),
                f"{b['model/drift_over_d']:.1e} / {b['truth/drift_over_d']:.1e}",
                fmt(b["ratio/msd_1_over_d2"]),
                fmt(b["ratio/msd_10_over_d2"]),
                fmt(b["ratio/msd_100_over_d2"]),
                fmt(b["ratio/rms_step_over_d"]),
                fmt(b["ratio/rms_non_affine_over_d"]),
                fmt(b["step_w1"]),
            ]
        )
    headers = [
        "frames",
        "overlap % model / truth",
        "g(r) L1",
        "Z ratio",
        "profile ratio",
        "drift d/frame model / truth",
        "MSD1",
        "MSD10",
        "MSD100",
        "RMS step",
        "RMS non-aff.",
        "step W1",
    ]
    return markdown_table(headers, rows)


def floor_line(scene: dict) -> str:
    floor = scene["noise_floor"]["blocks"]
    parts = [
        f"g(r) L1 {max(b['gr_l1'] for b in floor):.3g}",
        f"profile {100 * _worst(floor, 'ratio/profile'):.2g} %",
        f"RMS step {100 * _worst(floor, 'ratio/rms_step_over_d'):.2g} %",
        f"MSD lag 10 {100 * _worst(floor, 'ratio/msd_10_over_d2'):.2g} %",
        f"coordination {100 * _worst(floor, 'ratio/coordination'):.2g} %",
    ]
    return "noise floor (two independent DEM simulations, same blocks): " + ", ".join(parts)


def summary_tables(report: dict) -> str:
    out = [f"machine: {report['machine']}", ""]
    for scene, s in report["scenes"].items():
        b = s["breakdown_ms_per_frame"]
        out += [
            f"## {scene}: {s['frames']} predicted frames, link {s['settings']['link']}, "
            f"contact correction {'on' if s['settings']['contact_correction'] else 'off'}",
            "",
            f"speed: DEM {s['dem_ms_per_frame']:.1f} ms per frame, model "
            f"{s['model_ms_per_frame']:.2f} ms per frame ({s['speedup']:.1f}x); breakdown (ms per "
            "frame): " + ", ".join(f"{k} {v:.2f}" for k, v in b.items()),
            "",
        ]
        rm = s["rmse_over_d"]
        marks = [m for m in MARKS if m <= len(rm["model"])]
        rows = [[name] + [f"{v[m - 1]:.3g}" for m in marks] for name, v in rm.items()]
        out += [markdown_table(["RMSE / d at frame"] + [str(m) for m in marks], rows), ""]
        out += [block_table(s), "", floor_line(s), ""]
        hb = [
            [
                h["frame"],
                fmt(h.get("fluctuation_ratio", math.nan)),
                fmt(h.get("total_ratio", math.nan)),
                h["model"].get("error", fmt(h["model"].get("max_overlap_d", math.nan))),
            ]
            for h in s["handback"]
        ]
        out += [
            markdown_table(
                [
                    "hand-back frame",
                    "KE ratio (fluctuation)",
                    "KE ratio (total)",
                    "model restart: max overlap / d or error",
                ],
                hb,
            ),
            "",
        ]
        corr = s["correction"]
        if corr["overlapping_before"]:
            out.append(
                f"contact correction: {np.mean(corr['overlapping_before']):.0f} pairs per frame "
                f"overlapping before it (worst {max(corr['worst_overlap_before']):.2g} d), "
                f"RMS push {np.mean(corr['rms_push_over_d']):.2g} d"
            )
        out += ["", markdown_table(["target", "measured (worst)", "verdict"], targets(s)), ""]
    return "\n".join(out)
