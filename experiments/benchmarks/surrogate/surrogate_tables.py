"""Markdown tables of ``surrogate_rollout.py`` (a sibling module of the script): speed, short-term
RMSE, per-block statistics beside the noise floor, hand-back, and every target met or missed."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import fmt, markdown_table  # noqa: E402

from gripdem.evaluation.rollout_stats import SURROGATE_TARGETS  # noqa: E402

MARKS = (1, 10, 30, 100)


def _worst(blocks, key, target=1.0) -> float:
    """Largest |value - target| over the blocks (NaN ignored)."""
    values = [abs(b[key] - target) for b in blocks if not math.isnan(b.get(key, math.nan))]
    return max(values) if values else math.nan


def _all_blocks(scene: dict) -> list[dict]:
    """Every member's blocks (member 0's are ``blocks``; the others', ``member_blocks``)."""
    return scene["blocks"]["blocks"] + [b for m in scene.get("member_blocks", []) for b in m]


def _within(value: float, tolerance: float) -> bool | None:
    """Met, missed, or None where the rollout is too short to measure it."""
    return None if math.isnan(value) else value <= tolerance


def worst_deviations(scene: dict) -> dict[str, float]:
    """The block statistics' worst distance from the truth over the blocks and members, by
    name: ``msd_1``, ``msd_10``, ``msd_100``, ``rms_non_affine``, ``coordination``, ``profile``
    (|ratio - 1|), ``diffusion`` (|D / D_truth - 1|, the worst axis; NaN without it), ``gr_l1``
    (largest L1) and ``drift_over_d`` (the largest uniform drift, d per frame)."""
    blocks = _all_blocks(scene)
    out = {f"msd_{lag}": _worst(blocks, f"ratio/msd_{lag}_over_d2") for lag in (1, 10, 100)}
    out["rms_non_affine"] = _worst(blocks, "ratio/rms_non_affine_over_d")
    out["diffusion"] = math.nan
    if "diffusion" in scene:
        truth = np.asarray(scene["diffusion"]["truth"])
        out["diffusion"] = max(
            float(np.max(np.abs(np.asarray(m) / truth - 1))) for m in scene["diffusion"]["members"]
        )
    out["coordination"] = _worst(blocks, "ratio/coordination")
    out["profile"] = _worst(blocks, "ratio/profile")
    out["gr_l1"] = max(b["gr_l1"] for b in blocks)
    out["drift_over_d"] = max(abs(b["model/drift_over_d"]) for b in blocks)
    return out


def frames_above_baselines(scene: dict) -> int:
    """Predicted frames (of the report's first ones, frames 1-100) where the model's RMSE is
    above constant velocity's or the linear AR filter's."""
    rm = scene["rmse_over_d"]
    return sum(
        1
        for j, model in enumerate(rm["model"])
        if model > min(rm["constant_velocity"][j], rm["linear_ar"][j])
    )


def targets(scene: dict, reference: dict | None = None) -> list[list]:
    """The surrogate's targets (``SURROGATE_TARGETS``), worst over the blocks and the members."""
    blocks = _all_blocks(scene)
    worst = worst_deviations(scene)
    model_overlap = max(scene["blocks"]["overlap_per_frame"]["model"])
    n = len(scene["rmse_over_d"]["model"])
    losses = frames_above_baselines(scene)
    drift = worst["drift_over_d"]
    truth_drift = max(abs(b["truth/drift_over_d"]) for b in blocks)
    ratios = [h.get("fluctuation_ratio", math.inf) for h in scene["handback"]]
    t = SURROGATE_TARGETS
    rows = [
        [
            f"overlap <= {t['overlap']:.0%} every frame",
            fmt(100 * model_overlap) + " %",
            model_overlap <= t["overlap"],
        ]
    ]
    for lag in (1, 10, 100):
        value = worst[f"msd_{lag}"]
        rows.append(
            [
                f"non-affine MSD lag {lag} within {t['msd']:.0%}",
                fmt(value),
                _within(value, t["msd"]),
            ]
        )
    value = worst["rms_non_affine"]
    rows.append(
        [
            f"RMS non-affine step within {t['rms_non_affine']:.0%}",
            fmt(value),
            _within(value, t["rms_non_affine"]),
        ]
    )
    if "diffusion" in scene:
        value = worst["diffusion"]
        rows.append(
            [
                f"self-diffusion D_x, D_y, D_z within {t['diffusion']:.0%}",
                fmt(value),
                _within(value, t["diffusion"]),
            ]
        )
    for name, key, tol in (
        (
            f"contacts within 1.01 d within {t['coordination']:.0%}",
            "coordination",
            t["coordination"],
        ),
        (f"flow profile within {t['profile']:.0%}", "profile", t["profile"]),
    ):
        rows.append([name, fmt(worst[key]), _within(worst[key], tol)])
    gr = worst["gr_l1"]
    rows.append([f"g(r) L1 <= {t['gr_l1']:g} every block", fmt(gr), gr <= t["gr_l1"]])
    rows.append(
        [
            "uniform drift within the truth's noise",
            f"{drift:.2g} d/frame (truth {truth_drift:.2g})",
            drift <= 2 * truth_drift,
        ]
    )
    rows.append(
        [
            "hand-back fluctuation KE {:g}-{:g} of the truth's".format(*t["handback"]),
            ", ".join(fmt(r) for r in ratios),
            bool(ratios) and min(ratios) >= t["handback"][0] and max(ratios) <= t["handback"][1],
        ]
    )
    rows.append([f"RMSE <= CV and AR, frames 1-{n}", f"{losses} frame(s) above", losses == 0])
    if "spread_skill" in scene:
        ss = scene["spread_skill"]
        rows.append(
            [
                "spread/skill {:g}-{:g} at every frame 1-{}".format(*t["spread_skill"], len(ss)),
                f"{min(ss):.3g}-{max(ss):.3g}",
                min(ss) >= t["spread_skill"][0] and max(ss) <= t["spread_skill"][1],
            ]
        )
        hist = np.asarray(scene["rank_histogram"]) * len(scene["rank_histogram"])
        rows.append(
            [
                "rank histogram within {:g}-{:g}x of uniform".format(*t["rank_over_uniform"]),
                f"{hist.min():.2f}-{hist.max():.2f}",
                hist.min() >= t["rank_over_uniform"][0] and hist.max() <= t["rank_over_uniform"][1],
            ]
        )
    if reference is not None and scene["members"] > 1:
        mine, theirs = scene["crps_over_d"]["model"], reference["crps_over_d"]["model"]
        above = sum(1 for a, b in zip(mine, theirs, strict=False) if a >= b)
        rows.append(
            [
                "CRPS below the deterministic model's MAE at every frame",
                f"{above} frame(s) at or above",
                above == 0,
            ]
        )
        timing = scene.get("member_cost_ms")
        if timing:  # side by side, interleaved: one member each, then the members together
            one, ref = timing["ensemble, 1 member"], timing["reference, 1 member"]
            together = next(v for k, v in timing.items() if k.endswith("together"))
            cost = one / ref
            value = (
                f"{cost:.2f}x one member ({one:.2f} vs {ref:.2f} ms), "
                f"{together / ref:.2f}x per member with {scene['members']} together"
            )
        else:
            cost = scene["model_ms_per_frame"] / reference["model_ms_per_frame"]
            value = (
                f"{cost:.2f}x ({scene['model_ms_per_frame']:.2f} vs "
                f"{reference['model_ms_per_frame']:.2f} ms)"
            )
        rows.append(
            ["cost per member and frame <= 1.10x the deterministic model's", value, cost <= 1.10]
        )
    rows.append(
        ["50x faster than the DEM per frame", fmt(scene["speedup"]) + "x", scene["speedup"] >= 50]
    )
    verdict = {True: "met", False: "MISSED", None: "n/a (rollout too short)"}
    return [[name, value, verdict[None if ok is None else bool(ok)]] for name, value, ok in rows]


def ensemble_lines(scene: dict) -> list[str]:
    """Spread, calibration and CRPS of an ensemble (empty for one member)."""
    if scene.get("members", 1) < 2:
        return []
    ss, crps = scene["spread_skill"], scene["crps_over_d"]
    marks = [m for m in MARKS if m <= len(ss)]
    rows = [["spread/skill"] + [f"{ss[m - 1]:.3g}" for m in marks]]
    rows += [[f"CRPS / d {name}"] + [f"{v[m - 1]:.3g}" for m in marks] for name, v in crps.items()]
    rows.append(
        ["RMSE / d member 0"] + [f"{scene['member_rmse_over_d'][m - 1]:.3g}" for m in marks]
    )
    hist = ", ".join(f"{v * len(scene['rank_histogram']):.2f}" for v in scene["rank_histogram"])
    spread = scene["spread_over_d"]
    lines = [
        f"ensemble: {scene['members']} members (seed {scene['seed']}); block statistics above are "
        "member 0's, the targets below the worst over the members",
        "",
        markdown_table(["frame"] + [str(m) for m in marks], rows),
        "",
        f"rank histogram (frames 1-{len(ss)}, bins over uniform): {hist}",
        "spread (RMS distance of the members from their mean, d) per block: "
        + ", ".join(f"{v:.3g}" for v in spread),
    ]
    if "diffusion" in scene:
        truth = scene["diffusion"]["truth"]
        member = scene["diffusion"]["members"][0]
        lines.append(
            "self-diffusion D (d^2 per frame, x y z): truth "
            + " ".join(f"{v:.3g}" for v in truth)
            + ", member 0 "
            + " ".join(f"{v:.3g}" for v in member)
        )
    return lines + [""]


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
        reference = report["scenes"].get(f"{scene} (reference)")
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
        out += ensemble_lines(s)
        if "diffusion" in s and s.get("members", 1) < 2:
            out += [
                "self-diffusion D (d^2 per frame, x y z): truth "
                + " ".join(f"{v:.3g}" for v in s["diffusion"]["truth"])
                + ", model "
                + " ".join(f"{v:.3g}" for v in s["diffusion"]["members"][0]),
                "",
            ]
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
        table = markdown_table(["target", "measured (worst)", "verdict"], targets(s, reference))
        out += ["", table, ""]
    return "\n".join(out)
