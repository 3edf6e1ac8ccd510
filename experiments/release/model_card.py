"""The model card of a shipped model for people (``NAME.md`` beside ``NAME.safetensors``):
training data, training (split, horizon and rollout training), the out-of-sample test beside the
baselines, and for an ensemble its rollout settings and long-rollout statistics. Written by
``ship_pretrained.py`` from the model file's own card and hyperparameters."""

from __future__ import annotations

import math

from gripdem.evaluation.rollout_stats import SURROGATE_TARGETS

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


def split_sims(split: dict | None) -> str:
    """``: simulations [..] / [..] / [..] of the file`` of a card's split plan ('' without)."""
    if not split:
        return ""
    parts = " / ".join(str(split.get(f"sims_{p}", [])) for p in ("train", "val", "test"))
    return f": simulations {parts} of the file"


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


def shipped_in(card: dict) -> str:
    """``gripdem X`` (the release that ships the model), naming the version that trained it
    when that differs."""
    trained, shipped = card["gripdem_version"], card.get("shipped_in", card["gripdem_version"])
    return f"gripdem {shipped}" + ("" if shipped == trained else f", trained by {trained}")


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
        f"The {what} of the `{card['scene']}` scene ({shipped_in(card)}): "
        f"`python -m gripdem.predict pretrained:{name} DATA.h5`, "
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
        f"(generator version {data['provenance'].get('version', '?')}, gripdem "
        f"{data['provenance'].get('package_version', '?')}), seed "
        f"{params.get('seed')}, backend {params.get('backend')}",
        f"- preset `{preset.get('name')}`: frame interval {preset.get('frame_interval')} s, "
        f"spin-up {preset.get('spinup_time')} s, DEM step "
        f"{data['provenance'].get('derived', {}).get('dt', float('nan')):.3g} s "
        f"({format(preset.get('steps_per_contact', float('nan')), 'g')} steps per contact time)",
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
        f"epochs), lr {run.get('lr')} ({run.get('lr_schedule')}); training times, dated and with "
        "their machine: the result files of `experiments/results/`",
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
