"""Do the decoder modes differ? Every pair of modes compared on the same scene and split over
seeds, a difference within the seed spread reported as none.

    python experiments/analyses/mode_differences.py SWEEP_DIR [SWEEP_DIR ...]
        [--models grip pct vct]
        [--out experiments/results/decoder_modes/decoder_modes_differences.md]

Reads the jobs' ``metrics.json`` (grouped by scene, split and model over seeds, as
``sweep_report.py`` does) and, for each scene, split and pair of models, compares the test
RMSE with the rule of ``gripdem.claims`` (:func:`gripdem.evaluation.claims.beats`): the
difference of the means beyond 2 standard errors of the difference is a difference, anything
less is none. Writes the table to ``--out`` (after the result header) and prints it.
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import sys
from pathlib import Path

from gripdem.evaluation.claims import HELD, NOT_HELD, beats
from gripdem.evaluation.sweep_summary import runs_by_group
from gripdem.provenance import write_result


def ratio(groups, scene, split, model, key="test/rmse_ratio_constant_velocity") -> str:
    values = [m[key] for m in groups.get((scene, split, model), []) if key in m]
    if not values:
        return "–"
    if len(values) == 1:
        return f"{values[0]:.3f}"
    return f"{statistics.fmean(values):.3f} ± {statistics.stdev(values):.3f}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweeps", nargs="+", type=Path)
    parser.add_argument("--models", nargs="+", default=["grip", "pct", "vct"])
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("experiments/results/decoder_modes/decoder_modes_differences.md"),
    )
    args = parser.parse_args(argv)
    groups = runs_by_group(args.sweeps)
    scenes = sorted({k[0] for k in groups})
    splits = sorted({k[1] for k in groups}, key=lambda s: int(s.split("-")[1]))
    lines = [
        "# Decoder modes: differences over seeds",
        "",
        "Test RMSE ÷ CV (mean ± std over seeds); a difference of test RMSE / d counts when it "
        "exceeds 2 standard errors of the difference (the rule of `gripdem.claims`), "
        "otherwise it is none.",
        "",
        "| scene | split | A | B | A ÷ CV | B ÷ CV | difference of RMSE / d (B - A) | verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for scene, split in itertools.product(scenes, splits):
        for a, b in itertools.combinations(args.models, 2):
            if (scene, split, a) not in groups or (scene, split, b) not in groups:
                continue
            comparison = beats(groups, scene, split, a, b, "test/rmse_over_d", "RMSE / d")
            if comparison.verdict == HELD:
                verdict = f"{a} better"
            elif comparison.verdict == NOT_HELD:
                verdict = f"{b} better"
            else:
                verdict = "none (within the seed spread)"
            evidence = comparison.evidence.split("; ", 1)[1]
            lines.append(
                f"| {scene} | {split} | {a} | {b} | {ratio(groups, scene, split, a)} | "
                f"{ratio(groups, scene, split, b)} | {evidence} | {verdict} |"
            )
    text = "\n".join(lines) + "\n"
    write_result(args.out, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
