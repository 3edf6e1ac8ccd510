"""The microstructure figure of a shipped ensemble: contacts, g(r) distance and non-affine MSD
per block, the members beside the deterministic model and the DEM's noise floor
(:func:`gripdem.plots.microstructure.plot_microstructure`), from a ``surrogate_rollout.py``
report run with ``--members M --reference SCENE=...`` (never re-measured here).

    python experiments/analyses/microstructure_figure.py REPORT.json SCENE OUT.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from gripdem.plots.common import save_figure
from gripdem.plots.microstructure import plot_microstructure


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("report", type=Path)
    parser.add_argument("scene")
    parser.add_argument("out", type=Path)
    args = parser.parse_args(argv)
    scenes = json.loads(args.report.read_text())["scenes"]
    entry, reference = scenes[args.scene], scenes.get(f"{args.scene} (reference)")
    title = (
        f"{args.scene}: {entry['frames']} frames of a DEM run it never saw, "
        f"{entry['members']} members (statistics of {1 + len(entry.get('member_blocks', []))}), "
        f"{entry['blocks']['block']}-frame blocks"
    )
    save_figure(plot_microstructure(entry, reference, title), args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
