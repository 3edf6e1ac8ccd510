"""Hydra entry: generate a scene dataset with the built-in DEM.

    python -m gripdem.simulate scene=pbc|lebc [preset=tiny|default|paper] [sims=S] [out=PATH]
                               [seed=N] [backend=numba|torch device=cpu|cuda] [workers=W]

Writes a validated gripdem HDF5 (atomically) and its validation report
(``<stem>.validation.json`` + ``<stem>.profile.png``) next to it. Without ``out`` the file goes
to the dataset cache (:mod:`gripdem.data.cache`), where the experiment runner finds it.
Bad options end in one line ``error: ...`` (status 1); Ctrl-C stops every worker process and
writes nothing (status 130).
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

# light imports only: the DEM (numba, torch) loads inside run_hydra_command (a Ctrl-C or
# SIGTERM while it loads is answered in one line)
from gripdem.config_files import config_dir
from gripdem.runner.console import run_hydra_command, single_run_errors

log = logging.getLogger(__name__)
#: where this process is writing (for the Ctrl-C line)
_TARGETS: list[str] = []


def run(cfg: DictConfig) -> Path:
    """Generate (or find in the cache) the dataset described by ``cfg``; returns its path."""
    from gripdem.dem.config import GeneratorConfig
    from gripdem.dem.output import ensure_scene_dataset, generate_dataset
    from gripdem.dem.validation import report_paths

    _TARGETS.append("the dataset cache" if cfg.out is None else str(cfg.out))
    if cfg.out is None:
        path = ensure_scene_dataset(
            cfg.scene,
            cfg.preset,
            sims=cfg.sims,
            seed=cfg.seed,
            backend=cfg.backend,
            progress=cfg.progress,
            workers=cfg.workers,
            device=cfg.device,
        )
    else:
        config = GeneratorConfig.from_mappings(
            cfg.scene, cfg.preset, sims=cfg.sims, seed=cfg.seed, backend=cfg.backend
        )
        path, _ = generate_dataset(
            config,
            Path(cfg.out),
            overwrite=cfg.overwrite,
            progress=cfg.progress,
            workers=cfg.workers,
            device=cfg.device,
            strict=cfg.strict,
        )
    json_path, png_path = report_paths(path)
    if json_path.exists():
        report = json.loads(json_path.read_text())
        print(summary(report))
    print(f"dataset: {path}\nreport:  {json_path}\nprofile: {png_path}")
    return path


def summary(report: dict) -> str:
    """A few lines with the numbers that matter."""
    prof = report.get("velocity_profile", {})
    lines = [
        f"validation {'PASSED' if report.get('passed') else 'FAILED'}: "
        + ", ".join(f"{k}={'ok' if v else 'FAIL'}" for k, v in report.get("checks", {}).items()),
        f"  max overlap (frames) {report.get('max_overlap_frames_d', float('nan')):.2e} d, "
        f"profile R^2 {prof.get('fit_r2', float('nan')):.4f}, "
        "non-affine RMS over 10 frames "
        f"{report.get('nonaffine_rms_window_d', float('nan')):.3f} d, "
        f"x-face crossings per frame {report.get('x_crossings_per_frame', float('nan')):.2f}",
    ]
    if "generation_wall_time_s" in report:
        lines.append(f"  generated in {report['generation_wall_time_s']:.1f} s")
    return "\n".join(lines)


@hydra.main(version_base="1.3", config_path=str(config_dir()), config_name="simulate")
def main(cfg: DictConfig) -> None:
    with single_run_errors():
        run(cfg)


def nothing_written() -> str:
    target = _TARGETS[-1] if _TARGETS else "the dataset"
    return (
        f"DEM generation for {target}: nothing written (a dataset and its report are written "
        "only when complete) and no worker process left"
    )


if __name__ == "__main__":
    sys.exit(run_hydra_command("gripdem.simulate", main, nothing_written))
