"""Rollout training's ablation table: accuracy, training cost and the raw frames of trained runs.

    python experiments/analyses/rollout_training.py --runs RUN_DIR [RUN_DIR ...]
        [--windows 8] [--lean] [--out experiments/results/rollout_training/rollout_training]

Each ``RUN_DIR`` is one ``python -m gripdem.run`` output folder (``metrics.json``,
``checkpoints/best.ckpt``, ``.hydra/config.yaml``), e.g. every job folder of a multirun
(``multirun/DATE/TIME/*``). Runs that differ only in their seed form one row: mean ± std over
the seeds, each seed in brackets. Per row:

- the test's RMSE over constant velocity's and over the linear AR filter's (out of sample, the
  split's horizon chained with the contact correction, as ``gripdem.run`` tests it), the best
  validation RMSE, training steps per second (each run's own, two jobs side by side on the
  machine named in the header);
- at the split's last predicted frame: particles overlapping (within 0.98 d), the contact
  number and the mean squared displacement over the truth's (1: as the DEM);
- the raw frames, on ``--windows`` one-link windows of the test simulations (every 20 frames),
  before any correction: pairs overlapping by more than 1e-3 d and by more than 1e-4 d per frame
  (the truth's own count beyond 1e-4 d on the same frames beside), and, chained with the
  correction over the split's test windows, the pairs that reach the correction per frame and
  the correction's milliseconds per frame (one thread).

Rows are also told apart by the training data's DEM step (``preset.steps_per_contact`` of
the run's config: runs on data generated with another time step). ``--lean`` reads the runs'
own files only (accuracy, training speed and minutes, the last frame's physics) and skips the
raw frames and the corrected rollouts (which load every run's model and data).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

sys.path.insert(1, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from benchlib import fmt, markdown_table, write_report  # noqa: E402

from gripdem.boundary import NeighbourList  # noqa: E402
from gripdem.data.batch import collate_windows  # noqa: E402
from gripdem.inference.checkpoint import load_checkpoint_model  # noqa: E402
from gripdem.inference.stepper import Stepper, StepperSettings  # noqa: E402
from gripdem.runner.experiment import build_datamodule  # noqa: E402

#: overlap depths counted in raw frames, in diameters
DEPTHS = (1e-3, 1e-4)
#: the swept options a row is named by (the seed is averaged over)
ROW_KEYS = (
    *("scene", "split", "model", "rollout_links", "rollout_loss", "rollout_target"),
    *("rollout_start", "contact_loss", "history_noise", "history_len", "lr", "budget"),
    "steps_per_contact",
)


def overlapping_pairs(frame: np.ndarray, time: float, offset: float, model) -> np.ndarray:
    """Pairs of one frame ``(N, 3)`` overlapping by more than each of :data:`DEPTHS`."""
    d = model.diameter
    nl = NeighbourList(model.boundary.box, d, 0.0, model.boundary.image_velocity)
    nl.build(frame, offset, time)
    _, _, vec = nl.pairs(time, d)
    overlap = 1.0 - np.sqrt(np.einsum("pc,pc->p", vec, vec)) / d
    return np.array([(overlap > depth).sum() for depth in DEPTHS])


def raw_frames(model, dm, windows: int) -> dict:
    """One link from ``windows`` starts of the test simulations, no correction: overlapping
    pairs per frame, model and truth (see the module doc)."""
    k, link = int(model.hparams.history_len), int(model.hparams.horizon)
    reader, meta = dm.datasets["test"].reader, dm.meta
    times = dm.datasets["test"].times
    starts = [
        (sim, start)
        for sim in dm.plan.test.sims
        for start in range(0, meta.n_frames - k - 1 - link, 20)
    ][:windows]
    model_counts, true_counts = [], []
    for sim, start in starts:
        frames = reader.read(sim, start, start + k + 1 + link)  # (T, N, 3)
        t = times[sim, start : start + k + 1 + link]
        stepper = Stepper(
            model,
            frames[None, : k + 1],
            t[None, : k + 1],
            StepperSettings(contact_correction=False),
        )
        predicted = stepper.advance(link)[0]
        offsets = model.boundary.offset(t[k + 1 :])
        for j in range(link):
            model_counts.append(overlapping_pairs(predicted[j], t[k + 1 + j], offsets[j], model))
            true_counts.append(
                overlapping_pairs(frames[k + 1 + j], t[k + 1 + j], offsets[j], model)
            )
    m, tr = np.mean(model_counts, axis=0), np.mean(true_counts, axis=0)
    return {
        "windows": len(starts),
        "raw_pairs_1e-3": float(m[0]),
        "raw_pairs_1e-4": float(m[1]),
        "true_pairs_1e-4": float(tr[1]),
    }


def corrected_rollouts(model, dm) -> dict:
    """The split's test windows chained with the correction: pairs reaching it and its time."""
    frames, reaching, seconds = 0, 0, 0.0
    warm = collate_windows([dm.datasets["test"][0]])  # numba's kernels loaded before timing
    Stepper(model, warm.input_positions.transpose(1, 2).numpy(), warm.input_times.numpy()).advance(
        2
    )
    for i in range(len(dm.datasets["test"])):
        batch = collate_windows([dm.datasets["test"][i]])
        observed = batch.input_positions.transpose(1, 2).numpy()
        stepper = Stepper(model, observed, batch.input_times.numpy(), StepperSettings())
        stepper.advance(batch.horizon)
        frames += batch.horizon
        reaching += sum(stepper.report.overlapping_before)
        seconds += stepper.seconds["correction"]
    return {"pairs_to_correction": reaching / frames, "correction_ms": 1e3 * seconds / frames}


def measure(run: Path, windows: int, lean: bool = False) -> dict:
    metrics = json.loads((run / "metrics.json").read_text())
    cfg = OmegaConf.load(run / ".hydra" / "config.yaml")
    hp = metrics["hparams"]
    physics = "test/physics/{}/{}"
    # runs made before an option existed: its default
    before = {"rollout_links": 1, "rollout_start": 0.0, "contact_loss": 0.0, "history_noise": 0.0}
    before["rollout_target"] = "truth"  # the only target before the option existed
    row = {key: hp.get(key, before.get(key, "–")) for key in ROW_KEYS}
    if row["rollout_links"] == 1:  # one link: nothing is chained in training
        row.update(rollout_loss="–", rollout_target="–", rollout_start="–")
    row["budget"] = metrics["steps"]
    row["steps_per_contact"] = OmegaConf.select(cfg, "preset.steps_per_contact", default="–")
    row.update(
        run=run.name,
        seed=hp["seed"],
        ratio_cv=metrics["test/rmse_ratio_constant_velocity"],
        ratio_ar=metrics["test/rmse_ratio_linear_ar"],
        val_rmse_over_d=metrics["val/rmse_best"]
        * metrics["test/rmse_over_d"]
        / metrics["test/rmse"],
        steps_per_s=metrics["steps"] / metrics["train_seconds"],
        train_min=metrics["train_seconds"] / 60.0,
        overlap_last=metrics["hp/overlap_last_frame"],
        contacts=metrics[physics.format("model", "coordination_contact")]
        / metrics[physics.format("truth", "coordination_contact")],
        msd=metrics[physics.format("model", "msd_last_over_d2")]
        / metrics[physics.format("truth", "msd_last_over_d2")],
    )
    if lean:
        return row
    dm = build_datamodule(cfg, Path(metrics["data"]["path"]))
    model = load_checkpoint_model(run / "checkpoints" / "best.ckpt")
    with torch.no_grad():
        row.update(raw_frames(model, dm, windows))
        row.update(corrected_rollouts(model, dm))
    return row


def _order(value) -> tuple:
    """Sort key of a row key's element: numbers by value (3 before 10), then the rest as text."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return (0, float(value), "")
    return (1, 0.0, str(value))


def summarise(rows: list[dict]) -> tuple[str, list]:
    groups: dict = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in ROW_KEYS), []).append(row)
    columns = (
        ("ratio_cv", "÷ CV", 3),
        ("ratio_ar", "÷ AR", 3),
        ("val_rmse_over_d", "val RMSE / d", 3),
        ("steps_per_s", "steps / s", 3),
        ("train_min", "training min", 2),
        ("overlap_last", "overlap % last", 2),
        ("contacts", "contacts ÷ truth", 3),
        ("msd", "MSD ÷ truth", 3),
        ("raw_pairs_1e-3", "raw pairs > 1e-3 d", 3),
        ("raw_pairs_1e-4", "raw pairs > 1e-4 d (truth)", 3),
        ("pairs_to_correction", "pairs to correction", 3),
        ("correction_ms", "correction ms / frame", 2),
    )
    columns = tuple(c for c in columns if all(c[0] in row for row in rows))
    table = []
    for key, members in sorted(groups.items(), key=lambda kv: tuple(map(_order, kv[0]))):
        cells = list(key) + [len(members)]
        for name, _, digits in columns:
            values = np.array([m[name] for m in members], dtype=float)
            cell = fmt(values.mean(), digits)
            if len(values) > 1:
                cell += (
                    f" ± {fmt(values.std(ddof=1), 1)} ({', '.join(fmt(v, digits) for v in values)})"
                )
            if name == "raw_pairs_1e-4":
                cell += f" ({fmt(np.mean([m['true_pairs_1e-4'] for m in members]), 3)})"
            cells.append(cell)
        table.append(cells)
    headers = ["scene", "split", "model", "links", "loss", "target", "start", "contact"]
    headers += ["history noise", "history", "lr", "steps", "DEM steps per contact", "seeds"]
    headers += [c[1] for c in columns]
    return markdown_table(headers, table), table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=Path, nargs="+", required=True)
    parser.add_argument("--windows", type=int, default=8)
    parser.add_argument("--lean", action="store_true", help="the runs' own files only")
    parser.add_argument("--title", default=None, help="a first line of the report")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    runs = [run for run in args.runs if (run / "metrics.json").exists()]
    rows = [measure(run, args.windows, args.lean) for run in runs]
    table, _ = summarise(rows)
    if args.lean:
        what = (
            "Test RMSE over CV's and AR's at the split's horizon (out of sample, chained with "
            "the contact correction), training speed and minutes, the last frame's physics over "
            "the truth's; mean ± std over seeds, each seed in brackets. Steps per second and "
            "minutes"
        )
    else:
        what = (
            "Rollout training: test RMSE over CV's and AR's at the split's horizon (out of "
            "sample, chained with the contact correction), training speed, the last frame's "
            "physics over the truth's, and the raw frames before any correction (one link from "
            f"{args.windows} starts of the test simulations) beside the truth's; mean ± std over "
            "seeds, each seed in brackets. The validation RMSE is on each run's own validation "
            "windows (as many links as it trains): compare it only between rows of the same "
            "links. Steps per second"
        )
    text = (
        (f"{args.title}\n\n" if args.title else "")
        + what
        + ": each run's own, two runs side by side on the machine of the header (shared with "
        "other work at times: read them as rough).\n\n" + table
    )
    write_report(args.out, text, rows)


if __name__ == "__main__":
    main()
