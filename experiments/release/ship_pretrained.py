"""Ship trained runs as the package's pretrained models (``pretrained:NAME``).

    python experiments/release/ship_pretrained.py --run pbc=RUN_DIR lebc=RUN_DIR
        [--data pbc=DATA.h5 lebc=DATA.h5]

For each ``NAME=RUN_DIR`` (a ``python -m gripdem.run`` output folder) the run's data-only model
file ``checkpoints/best.safetensors`` is loaded (format and weights checked), its card completed
with the training data (:func:`gripdem.inference.checkpoint.training_data_card`: file, sizes,
scene, the generator and its configuration; read from ``--data`` when the run's card predates
it, default the cached built-in dataset of the run's scene and seed) and written, atomically, to
``gripdem/inference/pretrained/NAME.safetensors`` with ``NAME.md``: the same card for people.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from gripdem.data.dataset_io import read_meta
from gripdem.data.h5io import atomic_write_text
from gripdem.inference.checkpoint import load_checkpoint_model, training_data_card
from gripdem.inference.model_file import read_model_file, save_model_file
from gripdem.inference.pretrained import FOLDER

BASELINE_ROWS = (
    ("model", "test/rmse"),
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


def markdown_card(name: str, card: dict, size_bytes: int, n_weights: int) -> str:
    """The model card of ``pretrained:NAME`` for people."""
    run, metrics, data = card["run"], card["metrics"], card["training_data"]
    params = data["provenance"].get("parameters", {})
    scene_cfg, preset = params.get("scene", {}), params.get("preset", {})
    d = float(data["scene"]["diameter"])  # the training data's, as every model reads it
    lines = [
        f"# pretrained:{name}",
        "",
        f"The default gripdem model of the `{card['scene']}` scene (gripdem "
        f"{card['gripdem_version']}): `python -m gripdem.predict pretrained:{name} DATA.h5`, "
        f"or fine-tune with `python -m gripdem.run data.path=MINE.h5 scene={card['scene']} "
        f"model.init_from=pretrained:{name}`. {n_weights:,} weights, {size_bytes / 1e6:.2f} MB, "
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
        "simulation), history "
        f"{run.get('history_len')} frames, horizon {run.get('horizon')}",
        f"- model `{run.get('model')}`: encoder {run.get('encoder')}, {run.get('channels')} "
        f"channels, graph cut-off {run.get('graph_cutoff_d')} d, decoder "
        f"{run.get('decoder_mode')}, frame {run.get('frame')}, seed {run.get('seed')}",
        f"- {int(metrics.get('steps', 0))} optimiser steps ({int(metrics.get('epochs', 0))} "
        f"epochs), lr {run.get('lr')} ({run.get('lr_schedule')}), "
        f"{metrics.get('train_seconds', math.nan):.0f} s on 2 CPU cores",
        "",
        "## Out-of-sample test (held-out simulations, 10-frame horizon)",
        "",
        "| | RMSE (m) | RMSE / d | model / this |",
        "|---|---|---|---|",
    ]
    model = metrics["test/rmse"]
    for label, key in BASELINE_ROWS:
        if key in metrics:
            value = metrics[key]
            lines.append(f"| {label} | {value:.4g} | {value / d:.4g} | {model / value:.3f} |")
    lines += ["", "RMSE at each horizon step / d:", ""]
    steps = sorted(k for k in metrics if k.startswith("test/rmse_step/"))
    lines.append(" ".join(f"{metrics[k] / d:.2e}" for k in steps))
    return "\n".join(lines) + "\n"


def ship(name: str, run_dir: Path, data: str | None) -> Path:
    source = Path(run_dir) / "checkpoints" / "best.safetensors"
    model = load_checkpoint_model(source)
    _, _, card = read_model_file(source)
    card = dict(card)
    if "training_data" not in card:
        if data is None:
            raise SystemExit(f"error: {source}: its card has no training data; give --data")
        card["training_data"] = training_data_card(read_meta(data))
    card["shipped_as"] = f"pretrained:{name}"
    target = FOLDER / f"{name}.safetensors"
    FOLDER.mkdir(parents=True, exist_ok=True)
    save_model_file(model, target, card, overwrite=True)
    n_weights = sum(p.numel() for p in model.state_dict().values())
    text = markdown_card(name, card, target.stat().st_size, n_weights)
    atomic_write_text(FOLDER / f"{name}.md", text, overwrite=True)
    print(f"wrote {target} ({target.stat().st_size / 1e6:.2f} MB) and {name}.md")
    print(json.dumps({k: card["metrics"][k] for k in card["metrics"] if "ratio" in k}, indent=1))
    return target


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", nargs="+", required=True, metavar="NAME=RUN_DIR")
    parser.add_argument("--data", nargs="+", default=[], metavar="NAME=DATA.h5")
    args = parser.parse_args(argv)
    data = pairs(args.data, "--data")
    for name, run_dir in pairs(args.run, "--run").items():
        ship(name, Path(run_dir), data.get(name))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
