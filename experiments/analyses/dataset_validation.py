"""Do the built-in scenes' datasets look like the physics they claim? The generator's validation
figures of each scene's dataset of a preset, side by side.

    python experiments/analyses/dataset_validation.py [--preset default] [--scenes pbc lebc]
        [--variant 'KEY=VALUE ...' ...] [--out experiments/results/dem_data/dataset_validation]

Reads the ``<dataset>.validation.json`` that ``python -m gripdem.simulate`` (and the first run
that needs the dataset) writes beside it, generating the dataset first where the cache lacks it:
the largest overlap over the written frames and over every DEM step, the flow profile's fit
(R², the Lees-Edwards slope over the imposed shear rate, the periodic cosine's amplitude),
x-face crossings per frame, the RMS motion relative to the mean flow over a
10-frame window, the DEM's steps per simulation and the generation's wall time. Each
``--variant`` adds, per scene, the dataset with those preset keys set otherwise (a candidate
default beside the current one).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from benchlib import fmt, markdown_table, scene_dataset, write_report  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def validation_of(scene: str, preset: str, overrides: dict | None = None) -> tuple[Path, dict]:
    """The dataset of ``scene`` and ``preset`` with the preset's keys ``overrides`` (generated
    if missing) and its validation."""
    path = scene_dataset(scene, preset, overrides)
    report = path.with_name(path.name.removesuffix(".h5") + ".validation.json")
    if not report.is_file():
        raise SystemExit(f"{report}: no validation report beside {path.name}")
    return path, json.loads(report.read_text())


def parse_variant(text: str) -> dict:
    """``"steps_per_contact=20 spinup_time=9e-4"`` -> the preset keys it sets (YAML values)."""
    out = {}
    for item in text.split():
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"--variant: expected KEY=VALUE of preset keys, got {item!r}")
        out[key] = yaml.safe_load(value)
    return out


def row(scene: str, v: dict) -> list:
    profile = v["velocity_profile"]
    shape = (
        f"slope ÷ shear rate {profile['slope_over_shear_rate']:.5f}"
        if "slope_over_shear_rate" in profile
        else f"cosine amplitude {fmt(profile['amplitude'])} m/s"
    )
    return [
        scene,
        f"{v['sims']} x {v['frames']} x {v['particles']}",
        fmt(v["max_overlap_frames_d"]),
        fmt(v.get("max_overlap_all_steps_d")),
        f"{profile['shape']}: R² {profile['fit_r2']:.5f}, {shape}",
        fmt(v["x_crossings_per_frame"]),
        fmt(v["nonaffine_rms_window_d"]),
        v.get("dem_steps_per_sim", "–"),
        fmt(v.get("generation_wall_time_s")),
        "yes" if v["passed"] else "no: " + ", ".join(k for k, ok in v["checks"].items() if not ok),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="default")
    parser.add_argument("--scenes", nargs="+", default=["pbc", "lebc"])
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments/results/dem_data/dataset_validation"
    )
    parser.add_argument(
        "--variant",
        action="append",
        default=[],
        help="preset keys set otherwise, e.g. 'steps_per_contact=20': a row per scene beside "
        "the preset's own (repeatable)",
    )
    args = parser.parse_args(argv)
    variants = [("preset", {})] + [(v, parse_variant(v)) for v in args.variant]
    rows, data = [], {}
    for scene in args.scenes:
        for label, overrides in variants:
            path, v = validation_of(scene, args.preset, overrides)
            rows.append(
                row(scene, v) if not overrides else [f"{scene}, {label}", *row(scene, v)[1:]]
            )
            data[scene if not overrides else f"{scene} {label}"] = {"dataset": path.name, **v}
    headers = [
        "scene",
        "sims x frames x particles",
        "max overlap, frames (d)",
        "max overlap, every DEM step (d)",
        "flow profile fit",
        "x-face crossings per frame",
        "RMS non-affine motion, 10 frames (d)",
        "DEM steps per simulation",
        "generation wall time (s)",
        "checks passed",
    ]
    text = (
        f"# The built-in scenes' `{args.preset}` datasets: the generator's validation\n\n"
        "Each dataset's `.validation.json` (the checks of `python -m gripdem.simulate`); "
        "the generation's wall time is that of the run that made the cached file (whatever "
        "else ran on the machine then). A row named `scene, KEY=VALUE` is the same dataset "
        "with that preset key set otherwise (`--variant`).\n\n" + markdown_table(headers, rows)
    )
    write_report(args.out, text, data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
