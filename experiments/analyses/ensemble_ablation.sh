#!/usr/bin/env bash
# The ensemble ablation on the default contact encoder (docs/explanation/surrogate.md#ensembles):
# per scene, the ensemble fine-tuned from the shipped deterministic model (twice: the rollout
# settings off, and the shipped settings, so each run's 190-10 test scores its own noise), then
# 2000-frame rollouts against the same new DEM simulation (seed 777), 8 members (statistics of 4),
# 200-frame blocks, each lever alone and the chosen combination beside the deterministic model;
# then the table, the figures and (with SHIP=1) the shipped ensembles. About 80 min on 2 cores,
# or about 45 min with the scenes side by side (one process each, then the table):
#   bash experiments/analyses/ensemble_ablation.sh runs/ensembles
#   export TORCH_THREADS=1   # the trainings' torch threads (default: one per core)
#   SCENES=pbc TABLE=0 bash ... runs/ensembles & SCENES=lebc TABLE=0 bash ... runs/ensembles; wait
#   SCENES= bash experiments/analyses/ensemble_ablation.sh runs/ensembles    # the table only
set -euo pipefail
out=${1:-runs/ensembles}
python=${PYTHON:-.venv/bin/python}
read -r -a scenes <<< "${SCENES-pbc lebc}"
threads=${TORCH_THREADS:+torch_threads=$TORCH_THREADS}
declare -A capture=([pbc]=0.002 [lebc]=0.005) inflation=([pbc]=1.3 [lebc]=1.5)
rollout() {  # NAME ARGS...: one surrogate_rollout.py report in $out/rollouts
  "$python" experiments/benchmarks/surrogate/surrogate_rollout.py --block 200 --threads 1 \
    --out-dir "$out/rollouts" --name "$@"
}
for s in "${scenes[@]}"; do
  # the shipped deterministic model's 190-10 test (trained at 100-100 it has no 190-10 test of its
  # own): the fine-tuning path at learning rate 0 for one step, so the weights stay the shipped ones
  "$python" -m gripdem.run $threads scene=$s split=190-10 model.init_from=pretrained:$s finetune.lr=0 \
    trainer.max_steps=1 outputs.figures=false hydra.run.dir="$out/${s}_deterministic_190-10"
  base=(scene=$s model=ensemble model.init_from=pretrained:$s trainer.max_steps=1820)
  "$python" -m gripdem.run $threads "${base[@]}" model.contact_capture=0 model.noise_scale=1 \
    hydra.run.dir="$out/${s}_plain"
  "$python" -m gripdem.run $threads "${base[@]}" model.contact_capture=${capture[$s]} \
    model.noise_scale=${inflation[$s]} hydra.run.dir="$out/${s}_ship"
  ens=$out/${s}_ship/checkpoints/best.safetensors
  members=(--checkpoint $s=$ens --members 8 --stat-members 4 --seed 0)
  rollout ${s}_chosen "${members[@]}" --reference $s=pretrained:$s
  rollout ${s}_det_plain --checkpoint $s=pretrained:$s --contact-overlap 0
  rollout ${s}_det_capture --checkpoint $s=pretrained:$s --contact-capture ${capture[$s]}
  rollout ${s}_ens_alone "${members[@]}" --noise-scale 1 --contact-capture 0 --contact-overlap 0
  rollout ${s}_ens_capture "${members[@]}" --noise-scale 1 --contact-overlap 0
  rollout ${s}_ens_inflation "${members[@]}" --contact-capture 0 --contact-overlap 0
  rollout ${s}_ens_touching "${members[@]}" --contact-overlap 0
  "$python" experiments/analyses/microstructure_figure.py "$out/rollouts/${s}_chosen.json" $s \
    experiments/figures/ensemble_microstructure_$s.png
done
[ "${TABLE:-1}" = 1 ] || exit 0
rows=()
for s in pbc lebc; do
  det=$out/${s}_deterministic_190-10/metrics.json
  r=$out/rollouts
  plain=$out/${s}_plain/metrics.json ship=$out/${s}_ship/metrics.json
  rows+=(--row "$s|deterministic, pairs exactly touching|$det|$r/${s}_det_plain.json|$s")
  rows+=(--row "$s|deterministic + resting overlap|$det|$r/${s}_chosen.json|$s (reference)")
  rows+=(--row "$s|deterministic + contact capture ${capture[$s]}|$det|$r/${s}_det_capture.json|$s")
  rows+=(--row "$s|ensemble (default encoder), no lever|$plain|$r/${s}_ens_alone.json|$s")
  rows+=(--row "$s|ensemble + contact capture ${capture[$s]}|$plain|$r/${s}_ens_capture.json|$s")
  rows+=(--row "$s|ensemble + inflation ${inflation[$s]}|$ship|$r/${s}_ens_inflation.json|$s")
  rows+=(--row "$s|shipped without the resting overlap|$ship|$r/${s}_ens_touching.json|$s")
  rows+=(--row "$s|shipped: capture + inflation + resting overlap|$ship|$r/${s}_chosen.json|$s")
done
"$python" experiments/analyses/ensemble_ablation.py "${rows[@]}"
if [ "${SHIP:-0}" = 1 ]; then
  "$python" experiments/release/ship_pretrained.py \
    --run pbc-ensemble="$out/pbc_ship" lebc-ensemble="$out/lebc_ship" \
    --surrogate pbc-ensemble="$out/rollouts/pbc_chosen.json" \
    lebc-ensemble="$out/rollouts/lebc_chosen.json"
fi
