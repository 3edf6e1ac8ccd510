"""Long rollouts of several seeds side by side: how far each group of models' 2000-frame surrogate
runs stay from the DEM, mean ± std over the seeds.

    python experiments/analyses/surrogate_seeds.py \\
        --group "one link" A.json B.json C.json --group "rollout-trained" D.json E.json F.json \\
        [--entry "pbc (reference)=pbc, deterministic" ...]
        [--out experiments/results/rollout_training/surrogate_seeds]

Each JSON is a ``surrogate_rollout.py`` report (one model per scene, the same truth for all). Per
scene and group, each statistic's worst block (as the report's targets table reads it:
``surrogate_tables.worst_deviations``), the hand-back's largest distance of the fluctuation
kinetic energy from the truth's, and the short-term RMSE / d at frames 10 and 100; mean ± std
over the group's files, each file's value in brackets, in the order given. ``--entry
NAME=LABEL`` shows only the named entries of the reports (a scene, or ``SCENE (reference)``: the
deterministic model an ensemble's report rolls out beside it), each under its label.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "surrogate"))
from benchlib import add_group_option, group_files, markdown_table, write_report  # noqa: E402
from surrogate_tables import frames_above_baselines, worst_deviations  # noqa: E402

from gripdem.evaluation.rollout_stats import SURROGATE_TARGETS  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]

#: (statistic, its label, the target it is read against)
STATISTICS = (
    ("msd_1", "non-affine MSD lag 1", SURROGATE_TARGETS["msd"]),
    ("msd_10", "non-affine MSD lag 10", SURROGATE_TARGETS["msd"]),
    ("msd_100", "non-affine MSD lag 100", SURROGATE_TARGETS["msd"]),
    ("rms_non_affine", "RMS non-affine step", SURROGATE_TARGETS["rms_non_affine"]),
    ("diffusion", "self-diffusion, worst axis", SURROGATE_TARGETS["diffusion"]),
    ("coordination", "contacts within 1.01 d", SURROGATE_TARGETS["coordination"]),
    ("profile", "flow profile", SURROGATE_TARGETS["profile"]),
    ("gr_l1", "g(r) L1", SURROGATE_TARGETS["gr_l1"]),
    ("overlap", "overlapping particles (fraction, worst frame)", SURROGATE_TARGETS["overlap"]),
    ("drift_over_d", "uniform drift (d per frame)", None),
    ("frames_above", "frames 1-100 with RMSE above CV's or AR's", None),
    ("handback", "hand-back fluctuation KE", None),
    ("rmse_10", "RMSE / d at frame 10", None),
    ("rmse_100", "RMSE / d at frame 100", None),
)


def scene_values(scene: dict) -> dict[str, float]:
    """The statistics of :data:`STATISTICS` for one scene of one report."""
    values = worst_deviations(scene)
    ratios = [h.get("fluctuation_ratio", math.inf) for h in scene["handback"]]
    values["handback"] = max(abs(r - 1.0) for r in ratios) if ratios else math.nan
    values["overlap"] = max(scene["blocks"]["overlap_per_frame"]["model"])
    values["frames_above"] = frames_above_baselines(scene)
    rmse = scene["rmse_over_d"]["model"]
    values["rmse_10"] = rmse[9] if len(rmse) >= 10 else math.nan
    values["rmse_100"] = rmse[99] if len(rmse) >= 100 else math.nan
    return values


def cell(values: list[float]) -> str:
    """``mean ± std (each)``; one value alone."""
    shown = ", ".join(f"{v:.3g}" for v in values)
    if len(values) == 1:
        return shown
    return f"{np.mean(values):.3g} ± {np.std(values, ddof=1):.2g} ({shown})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_group_option(parser, "the surrogate_rollout.py JSON reports of its models")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments/results/rollout_training/surrogate_seeds"
    )
    parser.add_argument("--title", default="Long rollouts over seeds: worst block against the DEM")
    parser.add_argument(
        "--entry",
        action="append",
        default=[],
        metavar="NAME=LABEL",
        help="show only this entry of the reports, under LABEL (repeatable)",
    )
    args = parser.parse_args(argv)
    labels = {}
    for item in args.entry:
        name, sep, label = item.partition("=")
        if not sep or not name or not label:
            parser.error(f"--entry {item!r}: expected NAME=LABEL")
        labels[name] = label
    groups = {}
    for label, files in group_files(parser, args.group).items():
        reports = [json.loads(f.read_text())["scenes"] for f in files]
        if labels:
            reports = [{labels[k]: v for k, v in r.items() if k in labels} for r in reports]
        groups[label] = reports
    scenes = sorted({name for reports in groups.values() for r in reports for name in r})
    if labels:  # in the order the entries were given
        scenes = [label for label in labels.values() if label in scenes]
    rows, data = [], {}
    for scene in scenes:
        data[scene] = {}
        per_group = {
            label: [scene_values(r[scene]) for r in reports if scene in r]
            for label, reports in groups.items()
        }
        for key, label, target in STATISTICS:
            row = [scene, label, "–" if target is None else f"{target:g}"]
            for group, values in per_group.items():
                series = [v[key] for v in values if not math.isnan(v[key])]
                row.append(cell(series) if series else "–")
                data[scene].setdefault(group, {})[key] = series
            rows.append(row)
    text = (
        f"# {args.title}\n\n"
        "2000-frame surrogate runs of each model on the seed-777 DEM simulation "
        "(`experiments/benchmarks/surrogate/surrogate_rollout.py`, contact correction on); per "
        "statistic its worst block over the run: for a ratio to the truth's (MSD, RMS step, "
        "self-diffusion on its worst axis, contacts, flow profile, the hand-back's fluctuation "
        "kinetic energy), the largest distance from 1; mean ± std over the group's models, each in "
        "brackets. Target: the surrogate's targets "
        "(`gripdem.evaluation.rollout_stats.SURROGATE_TARGETS`), where one applies.\n\n"
        + markdown_table(["scene", "statistic", "target", *groups], rows)
    )
    write_report(args.out, text, data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
