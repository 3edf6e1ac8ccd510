"""Which pruner for gripdem's studies: Optuna's pruners replayed on the validation curves of a
study whose trials all trained their full budget.

    python experiments/analyses/pruner_replay.py STUDY_DIR [STUDY_DIR ...]
        [--out experiments/results/studies/pruner_replay]

Each trial folder's ``metrics.json`` holds its validation curve (``accuracy_curve``: the
validation RMSE over constant velocity's at each validation) and its best validation RMSE; the
curve in metres is the ratio times the trial's constant-velocity RMSE (its validation windows
are fixed). The trials are replayed in their order in the study, each pruner deciding at every
validation from the trials before it, as in a study run one trial at a time. Reported per
pruner: the training steps it would have spent (over the full study's), the trials it stops,
the rank (in the full study) of the best trial it keeps, and how many of the full study's three
best it keeps.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import optuna

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from benchlib import fmt, markdown_table, write_report  # noqa: E402

PRUNERS = {
    "none": lambda: optuna.pruners.NopPruner(),
    "median (5 startup trials)": lambda: optuna.pruners.MedianPruner(n_startup_trials=5),
    "median (5 startup, warm-up 2 validations)": lambda: optuna.pruners.MedianPruner(
        n_startup_trials=5, n_warmup_steps=700
    ),
    "successive halving (min = 1st validation, factor 3)": lambda: (
        optuna.pruners.SuccessiveHalvingPruner(min_resource=1, reduction_factor=3)
    ),
    "successive halving (min = 1st validation, factor 2)": lambda: (
        optuna.pruners.SuccessiveHalvingPruner(min_resource=1, reduction_factor=2)
    ),
    "successive halving (min = 1st validation, factor 4)": lambda: (
        optuna.pruners.SuccessiveHalvingPruner(min_resource=1, reduction_factor=4)
    ),
}


def load_trials(study_dirs: list[Path]) -> list[dict]:
    trials = []
    for study_dir in study_dirs:
        for metrics_file in sorted(study_dir.glob("trial=*/metrics.json")):
            metrics = json.loads(metrics_file.read_text())
            curve = metrics.get("accuracy_curve") or []
            best = metrics.get("val/rmse_best")
            if not curve or best is None:
                continue
            ratios = [ratio for _, _, ratio in curve]
            cv = best / min(ratios)  # the trial's constant-velocity RMSE on its windows
            number = int(metrics_file.parent.name.split(",")[0].split("=")[1])
            trials.append(
                {
                    "number": number,
                    "steps": [int(step) for _, step, _ in curve],
                    "values": [ratio * cv for ratio in ratios],
                    "best": float(best),
                    "budget": int(metrics.get("steps", curve[-1][1])),
                }
            )
    return sorted(trials, key=lambda t: t["number"])


def replay(trials: list[dict], make_pruner) -> dict:
    study = optuna.create_study(direction="minimize", pruner=make_pruner())
    spent, kept = 0, []
    for record in trials:
        trial = study.ask()
        stopped = None
        # SuccessiveHalving's resource is the step number: the k-th validation is step k
        for k, (step, value) in enumerate(
            zip(record["steps"], record["values"], strict=True), start=1
        ):
            trial.report(
                value,
                k if isinstance(study.pruner, optuna.pruners.SuccessiveHalvingPruner) else step,
            )
            if trial.should_prune():
                stopped = step
                break
        if stopped is None:
            study.tell(trial, record["best"])
            spent += record["budget"]
            kept.append(record)
        else:
            study.tell(trial, state=optuna.trial.TrialState.PRUNED)
            spent += stopped
    full_rank = {t["number"]: r for r, t in enumerate(sorted(trials, key=lambda t: t["best"]), 1)}
    best_kept = min(kept, key=lambda t: t["best"]) if kept else None
    top3 = {n for n, r in full_rank.items() if r <= 3}
    return {
        "steps_fraction": spent / sum(t["budget"] for t in trials),
        "pruned": len(trials) - len(kept),
        "best_kept_rank": full_rank[best_kept["number"]] if best_kept else None,
        "top3_kept": len(top3 & {t["number"] for t in kept}),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("studies", nargs="+", type=Path)
    parser.add_argument(
        "--out", type=Path, default=Path("experiments/results/studies/pruner_replay")
    )
    args = parser.parse_args()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    trials = load_trials(args.studies)
    if not trials:
        raise SystemExit(f"no trial with a validation curve under {args.studies}")
    results = {name: replay(trials, make) for name, make in PRUNERS.items()}
    headers = ["pruner", "steps spent ÷ all", "trials stopped", "best kept: rank", "top 3 kept"]
    rows = [
        [
            name,
            fmt(r["steps_fraction"]),
            f"{r['pruned']} of {len(trials)}",
            str(r["best_kept_rank"]),
            f"{r['top3_kept']} of 3",
        ]
        for name, r in results.items()
    ]
    spacing = sorted(
        {b - a for t in trials for a, b in zip(t["steps"], t["steps"][1:], strict=False)}
    )
    text = (
        f"{len(trials)} trials that trained their full budget, validated every "
        f"{spacing[0]}-{spacing[-1]} steps, replayed in study order with each pruner deciding "
        "at every validation from the trials before it.\n\n" + markdown_table(headers, rows)
    )
    write_report(args.out, text, {"trials": len(trials), "pruners": results})


if __name__ == "__main__":
    main()
