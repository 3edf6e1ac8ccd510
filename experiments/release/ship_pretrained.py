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
import sys
from pathlib import Path

from hydra import compose, initialize_config_dir

from gripdem._version import __version__
from gripdem.data.dataset_io import read_meta
from gripdem.data.h5io import atomic_write_text
from gripdem.data.protocols import plan_windows
from gripdem.inference.checkpoint import SPLIT_KEYS, load_checkpoint_model, training_data_card
from gripdem.inference.model_file import read_model_file, save_model_file
from gripdem.inference.pretrained import FOLDER
from gripdem.run import CONFIG_DIR

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "analyses"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from ensemble_ablation import statistics_ranges  # noqa: E402
from model_card import markdown_card  # noqa: E402


def pairs(values: list[str], what: str) -> dict[str, str]:
    out = {}
    for value in values or []:
        name, sep, rest = value.partition("=")
        if not sep or not name or not rest:
            raise SystemExit(f"error: {what} {value!r}: expected NAME=PATH")
        out[name] = rest
    return out


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
    card["shipped_in"] = __version__  # the card's gripdem_version: the training run's
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
