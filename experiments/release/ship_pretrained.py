"""Ship trained runs as the package's pretrained models (``pretrained:NAME``).

    python experiments/release/ship_pretrained.py --run pbc=RUN_DIR lebc=RUN_DIR
        [--data pbc=DATA.h5 lebc=DATA.h5] [--surrogate pbc-ensemble=REPORT.json]
    python experiments/release/ship_pretrained.py --split-cards pbc lebc
    python experiments/release/ship_pretrained.py --cards pbc lebc [--check]

For each ``NAME=RUN_DIR`` (a ``python -m gripdem.run`` output folder) the run's data-only model
file ``checkpoints/best.safetensors`` is loaded (format and weights checked), its card completed
with the training data (:func:`gripdem.inference.checkpoint.training_data_card`: file, sizes,
scene, the generator and its configuration; read from ``--data`` when the run's card predates
it) and its split plan (which simulations trained, validated and tested it: from the run's
``metrics.json`` when the card predates it) and written, atomically, to
``gripdem/inference/pretrained/NAME.safetensors`` with ``NAME.md``: the same card for people.

``--surrogate NAME=REPORT.json`` adds the long-rollout statistics of a ``surrogate_rollout.py``
report of that model (its scene's entry: ranges over the blocks and members, beside the
deterministic reference's when the report has one) to the card: the shipped ensembles' cards
say what their members were measured to do over 2000 frames.

``--split-cards NAME ...`` adds the split plan to shipped cards that predate it, in place (the
same tensors): the plan the run made, rebuilt from the card (the data's sizes, the run's split,
protocol and history) and the data config's defaults (fractions, explicit simulation lists).

``--cards NAME ...`` rewrites ``NAME.md`` from the shipped file alone (card and hyperparameters;
the file itself is not touched); with ``--check`` it writes nothing and fails, naming the file,
when a ``NAME.md`` differs from what its model file says (a default-tier test runs it).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from hydra import compose, initialize_config_dir

from gripdem.data.dataset_io import read_meta
from gripdem.data.h5io import atomic_write_text
from gripdem.data.protocols import plan_windows
from gripdem.evaluation.rollout_stats import SURROGATE_TARGETS
from gripdem.inference.checkpoint import SPLIT_KEYS, load_checkpoint_model, training_data_card
from gripdem.inference.model_file import read_model_file, save_model_file
from gripdem.inference.pretrained import FOLDER
from gripdem.run import CONFIG_DIR

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "analyses"))
from ensemble_ablation import statistics_ranges  # noqa: E402

_T = SURROGATE_TARGETS


def _pct(fraction: float) -> str:
    return f"{100 * fraction:g} %"


#: the long-rollout statistics a card shows: (key, label, target), the targets of
#: gripdem.evaluation.rollout_stats.SURROGATE_TARGETS
SURROGATE_ROWS = (
    ("coordination", "contacts within 1.01 d", "±" + _pct(_T["coordination"])),
    ("gr_l1", "g(r) L1 distance (two DEM runs: the report's noise floor)", f"≤ {_T['gr_l1']:g}"),
    ("msd_1", "non-affine MSD, lag 1", "±" + _pct(_T["msd"])),
    ("msd_10", "non-affine MSD, lag 10", "±" + _pct(_T["msd"])),
    ("msd_100", "non-affine MSD, lag 100", "±" + _pct(_T["msd"])),
    ("diffusion", "self-diffusion D (x, y, z)", "±" + _pct(_T["diffusion"])),
    ("profile", "flow profile", "±" + _pct(_T["profile"])),
    ("overlap_pct", "overlap (% of particles, worst frame)", "≤ " + _pct(_T["overlap"])),
    ("spread_skill", "spread/skill, frames 1-100", "{:g}-{:g}".format(*_T["spread_skill"])),
    (
        "rank_over_uniform",
        "rank histogram bins ÷ uniform, frames 1-100",
        "{:g}-{:g}".format(*_T["rank_over_uniform"]),
    ),
)

BASELINE_ROWS = (
    ("model", "test/rmse"),
    ("the model it was fine-tuned from", "before/test/rmse"),
    ("constant velocity", "test/rmse_constant_velocity"),
    ("linear AR", "test/rmse_linear_ar"),
    ("mean flow", "test/rmse_mean_flow"),
)


def pairs(values: list[str], what: str) -> dict[str, str]:
    out = {}
    for value in values or []:
        name, sep, rest = value.partition("=")
        if not sep or not name or not rest:
            raise SystemExit(f"error: {what} {value!r}: expected NAME=PATH")
        out[name] = rest
    return out


def split_sims(split: dict | None) -> str:
    """``: simulations [..] / [..] / [..] of the file`` of a card's split plan ('' without)."""
    if not split:
        return ""
    parts = " / ".join(str(split.get(f"sims_{p}", [])) for p in ("train", "val", "test"))
    return f": simulations {parts} of the file"


def planned_split(card: dict) -> dict:
    """The split plan of the run behind ``card`` (see the module doc), as the card keeps it."""
    run, data = card["run"], card["training_data"]
    overrides = [f"scene={card['scene']}", f"split={card['split']}"]
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("config", overrides=overrides).data
    plan = plan_windows(
        int(data["simulations"]),
        int(data["frames"]),
        card["split"],
        protocol=run["protocol"],
        history_len=run["history_len"],
        train_stride=int(cfg.train_stride),
        eval_stride=cfg.eval_stride,
        fractions=dict(cfg.fractions),
        sims=dict(cfg.sims),
        simulations=cfg.simulations,
        in_sample_windows=int(cfg.in_sample_windows),
    )
    summary = plan.summary()
    return {key: summary[key] for key in SPLIT_KEYS if key in summary}


def encoder_text(encoder: dict) -> str:
    """What the model's encoder is, from its hyperparameters (the shipped file's, not a
    description written by hand)."""
    from gripdem.models.encoder_options import encoder_options

    options = encoder_options(encoder)
    name = options.get("name", "graph_conv")
    if name != "contact":
        return f"encoder {name}, {options.get('channels')} channels"
    pair = options.get("pair_channels") or options.get("channels")
    updates = "with" if options.get("edge_updates") else "no"
    return (
        f"encoder {name}: {options.get('channels')} node and {pair} pair channels, "
        f"{options.get('rounds')} rounds, {options.get('edge_history')} relative-motion steps "
        f"per pair, {updates} edge updates"
    )


def surrogate_card(report_path: str, scene: str) -> dict:
    """The card's long-rollout section from a ``surrogate_rollout.py`` report."""
    report = json.loads(Path(report_path).read_text())
    entry = report["scenes"][scene]
    reference = report["scenes"].get(f"{scene} (reference)")
    return {
        "report": Path(report_path).name,
        "truth": Path(entry["truth"]).name,
        "frames": entry["frames"],
        "block": entry["blocks"]["block"],
        "members": entry["members"],
        "members_with_statistics": 1 + len(entry.get("member_blocks", [])),
        "seed": entry["seed"],
        "settings": entry["settings"],
        "ranges": statistics_ranges(entry),
        "reference": None if reference is None else statistics_ranges(reference),
        "member_cost_ms": entry.get("member_cost_ms"),
    }


def _cell(value) -> str:
    if value is None:
        return "–"
    if isinstance(value, list):
        return f"{value[0]:.3g}-{value[1]:.3g}"
    return f"{value:.3g}"


def surrogate_lines(hparams: dict, surrogate: dict) -> list[str]:
    """The card's rollout settings and long-rollout statistics, for people."""
    ranges, reference = surrogate["ranges"], surrogate.get("reference") or {}
    lines = [
        "## Rollouts",
        "",
        f"- contact capture {hparams.get('contact_capture', 0.0)} contact distances (pairs "
        "closer are pulled into contact in the correction), noise inflation "
        f"{hparams.get('noise_scale', 1.0)} (the members' latent noise times this outside "
        "training); both recorded in the file and used by `gripdem.predict` unless "
        "`--contact-capture` / `--noise-scale` say otherwise",
        "",
        f"Measured over {surrogate['frames']} frames of a DEM simulation it never saw "
        f"(`{surrogate['truth']}`), {surrogate['members']} members (seed {surrogate['seed']}; "
        f"statistics of {surrogate['members_with_statistics']}), per {surrogate['block']}-frame "
        "block, model / truth (ranges over the blocks and members; report "
        f"`{surrogate['report']}`):",
        "",
        "| statistic | target | members | deterministic model |",
        "|---|---|---|---|",
    ]
    for key, label, target in SURROGATE_ROWS:
        lines.append(
            f"| {label} | {target} | {_cell(ranges.get(key))} | {_cell(reference.get(key))} |"
        )
    cost = surrogate.get("member_cost_ms") or {}
    if cost:
        parts = "; ".join(f"{name}: {ms:.2f}" for name, ms in sorted(cost.items()))
        lines += ["", f"ms per member and frame, interleaved in one run: {parts}"]
    return lines + [""]


def chained(run: dict, hparams: dict) -> bool:
    """Whether the test chained links shorter than the split's horizon."""
    link = hparams.get("horizon")
    return link is not None and int(link) < int(run.get("horizon") or 0)


def horizon_text(run: dict, hparams: dict) -> str:
    """The split's horizon, and for a model of shorter links how it trained on them."""
    text = f"horizon {run.get('horizon')}"
    if not chained(run, hparams):
        return text
    text += f" in chained links of {hparams['horizon']} frames"
    links = int(run.get("rollout_links") or 1)
    if links > 1:
        text += (
            f"; rollout training: {links} links per window (loss {run.get('rollout_loss')}, "
            f"target {run.get('rollout_target')}; the first link alone for the first "
            f"{run.get('rollout_start')} of the budget)"
        )
    return text


def markdown_card(
    name: str, card: dict, size_bytes: int, n_weights: int, hparams: dict | None = None
) -> str:
    """The model card of ``pretrained:NAME`` for people."""
    run, metrics, data = card["run"], card["metrics"], card["training_data"]
    encoder = (
        encoder_text(dict(hparams["encoder"]))
        if hparams and hparams.get("encoder")
        else f"encoder {run.get('encoder')}, {run.get('channels')} channels"
    )
    params = data["provenance"].get("parameters", {})
    scene_cfg, preset = params.get("scene", {}), params.get("preset", {})
    d = float(data["scene"]["diameter"])  # the training data's, as every model reads it
    ensemble = int(dict((hparams or {}).get("encoder") or {}).get("noise_channels") or 0) > 0
    what = (
        "ensemble model (one forward pass is one member)" if ensemble else "default gripdem model"
    )
    lines = [
        f"# pretrained:{name}",
        "",
        f"The {what} of the `{card['scene']}` scene (gripdem "
        f"{card['gripdem_version']}): `python -m gripdem.predict pretrained:{name} DATA.h5`, "
        f"or fine-tune with `python -m gripdem.run data.path=MINE.h5 scene={card['scene']} "
        + ("model=ensemble " if ensemble else "")
        + f"model.init_from=pretrained:{name}`. {n_weights:,} weights, {size_bytes / 1e6:.2f} MB, "
        "data only (safetensors with a JSON card; nothing is unpickled).",
        "",
        "## Training data",
        "",
        f"- file `{data['file']}`: {data['simulations']} simulations x {data['frames']} frames x "
        f"{data['particles']} particles, boundary `{data['scene']['boundary']}`",
        f"- generator `{data['provenance'].get('generator')}` "
        f"(version {data['provenance'].get('package_version', '?')}), seed "
        f"{params.get('seed')}, backend {params.get('backend')}",
        f"- preset `{preset.get('name')}`: frame interval {preset.get('frame_interval')} s, "
        f"spin-up {preset.get('spinup_time')} s",
        "- scene: " + ", ".join(f"{k} {v}" for k, v in sorted(scene_cfg.items())),
        "",
        "## Training",
        "",
        f"- split {card['split']} ({run.get('protocol')} protocol: train/validation/test by "
        f"simulation{split_sims(data.get('split'))}), history "
        f"{run.get('history_len')} frames, {horizon_text(run, hparams or {})}",
        f"- model `{run.get('model')}`: {encoder}, graph cut-off {run.get('graph_cutoff_d')} "
        "d, decoder "
        f"{run.get('decoder_mode')}, frame {run.get('frame')}, seed {run.get('seed')}",
        f"- {int(metrics.get('steps', 0))} optimiser steps ({int(metrics.get('epochs', 0))} "
        f"epochs), lr {run.get('lr')} ({run.get('lr_schedule')}), "
        f"{metrics.get('train_seconds', math.nan):.0f} s on 2 CPU cores",
        "",
        f"## Out-of-sample test (held-out simulations, {run.get('horizon')}-frame horizon"
        + (", chained links with the contact correction)" if chained(run, hparams or {}) else ")"),
        "",
        "| | RMSE (m) | RMSE / d | model / this |",
        "|---|---|---|---|",
    ]
    model = metrics["test/rmse"]
    for label, key in BASELINE_ROWS:
        if key in metrics:
            value = metrics[key]
            lines.append(f"| {label} | {value:.4g} | {value / d:.4g} | {model / value:.3f} |")
    steps = sorted(k for k in metrics if k.startswith("test/rmse_step/"))
    if len(steps) <= 10:
        lines += ["", "RMSE at each horizon step / d:", ""]
        lines.append(" ".join(f"{metrics[k] / d:.2e}" for k in steps))
    else:  # step 1, then every tenth
        shown = [steps[0], *steps[9::10]]
        lines += ["", "RMSE / d at horizon steps " + ", ".join(str(int(k[-3:])) for k in shown)]
        lines += ["", " ".join(f"{metrics[k] / d:.2e}" for k in shown)]
    if "test/crps_over_d" in metrics and ensemble:
        lines += [
            "",
            f"An 8-member ensemble's mean is scored above; its CRPS / d "
            f"{metrics['test/crps_over_d']:.3g}, spread/skill at step 1 / 10 "
            f"{metrics.get('test/spread_skill_step/001', math.nan):.2f} / "
            f"{metrics.get('test/spread_skill_step/010', math.nan):.2f}, rank histogram bins "
            f"{metrics.get('test/rank_min_over_uniform', math.nan):.2f}-"
            f"{metrics.get('test/rank_max_over_uniform', math.nan):.2f} of uniform.",
        ]
    if card.get("surrogate"):
        lines += ["", *surrogate_lines(hparams or {}, card["surrogate"])]
    return "\n".join(lines).rstrip("\n") + "\n"


def write_shipped(name: str, model, card: dict) -> Path:
    """``NAME.safetensors`` (atomically) and ``NAME.md`` in the package's pretrained folder."""
    target = FOLDER / f"{name}.safetensors"
    FOLDER.mkdir(parents=True, exist_ok=True)
    if isinstance(model, tuple):  # (hparams, state dict) of a shipped file: the same tensors
        save_model_file(model[0], target, card, state_dict=model[1], overwrite=True)
        hparams, state = model
    else:
        save_model_file(model, target, card, overwrite=True)
        hparams, state = dict(model.hparams), model.state_dict()
    n_weights = sum(p.numel() for p in state.values())
    text = markdown_card(name, card, target.stat().st_size, n_weights, hparams)
    atomic_write_text(FOLDER / f"{name}.md", text, overwrite=True)
    print(f"wrote {target} ({target.stat().st_size / 1e6:.2f} MB) and {name}.md")
    return target


def ship(name: str, run_dir: Path, data: str | None, surrogate: str | None = None) -> Path:
    source = Path(run_dir) / "checkpoints" / "best.safetensors"
    model = load_checkpoint_model(source)
    _, _, card = read_model_file(source)
    card = dict(card)
    if "training_data" not in card:
        if data is None:
            raise SystemExit(f"error: {source}: its card has no training data; give --data")
        card["training_data"] = training_data_card(read_meta(data))
    if "split" not in card["training_data"]:  # a card that predates it: the run's record
        summary = json.loads((Path(run_dir) / "metrics.json").read_text())["data"]
        card["training_data"]["split"] = {k: summary[k] for k in SPLIT_KEYS if k in summary}
    card["shipped_as"] = f"pretrained:{name}"
    if surrogate:
        card["surrogate"] = surrogate_card(surrogate, card["scene"])
    target = write_shipped(name, model, card)
    print(json.dumps({k: card["metrics"][k] for k in card["metrics"] if "ratio" in k}, indent=1))
    return target


def split_card(name: str) -> Path:
    """Add the planned split to the card of the shipped ``pretrained:NAME`` (same tensors)."""
    hparams, state, card = read_model_file(FOLDER / f"{name}.safetensors")
    card["training_data"]["split"] = planned_split(card)
    print(f"pretrained:{name}: {card['training_data']['split']}")
    return write_shipped(name, (hparams, state), card)


def card_text(name: str) -> str:
    """``NAME.md`` as the shipped ``NAME.safetensors`` says it should read."""
    path = FOLDER / f"{name}.safetensors"
    hparams, state, card = read_model_file(path)
    n_weights = sum(p.numel() for p in state.values())
    return markdown_card(name, card, path.stat().st_size, n_weights, hparams)


def cards(names: list[str], check: bool) -> int:
    """Rewrite (or, with ``check``, compare) the ``.md`` cards of shipped models."""
    stale = []
    for name in names:
        text, target = card_text(name), FOLDER / f"{name}.md"
        if check:
            if not target.exists() or target.read_text() != text:
                stale.append(target)
            continue
        atomic_write_text(target, text, overwrite=True)
        print(f"wrote {target}")
    for target in stale:
        print(
            f"error: {target} differs from what {target.with_suffix('.safetensors').name} says; "
            "run experiments/release/ship_pretrained.py --cards " + " ".join(names),
            file=sys.stderr,
        )
    return 1 if stale else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", nargs="+", default=[], metavar="NAME=RUN_DIR")
    parser.add_argument("--data", nargs="+", default=[], metavar="NAME=DATA.h5")
    parser.add_argument("--surrogate", nargs="+", default=[], metavar="NAME=REPORT.json")
    parser.add_argument("--split-cards", nargs="+", default=[], metavar="NAME")
    parser.add_argument("--cards", nargs="+", default=[], metavar="NAME")
    parser.add_argument("--check", action="store_true", help="with --cards: compare only")
    args = parser.parse_args(argv)
    if args.cards:
        return cards(args.cards, args.check)
    if not args.run and not args.split_cards:
        parser.error("give --run NAME=RUN_DIR ..., --split-cards NAME ... or --cards NAME ...")
    for name in args.split_cards:
        split_card(name)
    data, reports = pairs(args.data, "--data"), pairs(args.surrogate, "--surrogate")
    for name, run_dir in pairs(args.run, "--run").items():
        ship(name, Path(run_dir), data.get(name), reports.get(name))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
