#!/usr/bin/env bash
# The model-size grid behind experiments/results/model_cost/model_front.md (the time-vs-error front):
# the default scene of each given scene, split 190-10, the fast preset, seed 0, one run per
# configuration, trained one after the other (each uses both cores), then measured by
# experiments/benchmarks/surrogate/model_front.py.
#   bash experiments/analyses/model_front.sh [OUT=multirun/front] [SCENES="pbc lebc"]
set -euo pipefail
out=${1:-multirun/front}
scenes=${2:-pbc}
python=${PYTHON:-.venv/bin/python}
configs=(
  "c64r4_gru:model.decoder=gru model.zero_mean=false"
  "c64r4:model.encoder.channels=64 model.encoder.rounds=4"
  "c48r3:model.encoder.channels=48 model.encoder.rounds=3"
  "c32r4:model.encoder.channels=32 model.encoder.rounds=4"
  "c32r3:model.encoder.channels=32 model.encoder.rounds=3"
  "c32r2:model.encoder.channels=32 model.encoder.rounds=2"
  "c32r3_cut1.2:model.encoder.channels=32 model.encoder.rounds=3 model.encoder.cutoff=1.2"
  "c32r3_K5:model.encoder.channels=32 model.encoder.rounds=3 data.history_len=5"
)
runs=()
for scene in $scenes; do
  for spec in "${configs[@]}"; do
    name=${spec%%:*}
    dir="$out/$scene-$name"
    if [ ! -f "$dir/metrics.json" ]; then
      # shellcheck disable=SC2086
      "$python" -m gripdem.run scene="$scene" ${spec#*:} hydra.run.dir="$dir" \
        outputs.export_xyz=false
    fi
    runs+=("$dir")
  done
done
"$python" experiments/benchmarks/surrogate/model_front.py "${runs[@]}" --threads 1 2 --links 10 1
