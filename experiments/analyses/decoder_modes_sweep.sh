#!/usr/bin/env bash
# The decoder modes compared (docs/explanation/results.md#decoder-modes): grip, pct and vct on the
# default encoder, decoder, prior and budget (they differ only in the mode; model=contact is
# grip under its own name), both scenes, the splits 190-10 and 100-100, seeds 0-2, with the default
# parallel launcher (two one-thread jobs at a time on 2 cores: about 75 min there), then the
# tables and figures:
#   bash experiments/analyses/decoder_modes_sweep.sh multirun/decoder_modes
set -euo pipefail
out=${1:-multirun/decoder_modes}
python=${PYTHON:-.venv/bin/python}
"$python" -m gripdem.run -m scene=pbc,lebc split=190-10,100-100 model=grip,pct,vct seed=0,1,2 \
  hydra.sweep.dir="$out" || true  # a failed job is named in the summary; report the others
"$python" experiments/analyses/sweep_report.py "$out" --out experiments/results/decoder_modes --name decoder_modes
"$python" experiments/analyses/mode_differences.py "$out"
"$python" -m gripdem.claims "$out" --out experiments/results/decoder_modes/claims
