#!/usr/bin/env bash
# Issue #14 end to end: a short paper-preset run, calibration frames, int8 recipes (per-layer sensitivity on
# validation frames) and gate verdicts on the pooled held-out bags, for the shipped models and the paper run.
# Reads the data set of scripts/default_model.sh (DATA, default data/v2: training and validation bags, the
# held-out gate bags; it collects what is missing). Resumable: collection skips finished bags, the paper run is
# skipped once its best.pt exists, calibration frames are rebuilt only for a checkpoint newer than them.
#   CHECKPOINTS="models/msfsu_default.pt" bash scripts/int8_gate.sh     # one model (no paper run unless listed)
# About 1 h on 2 cores with the paper run. The perception tables of docs/deployment.md come from what it writes:
#   python scripts/readme_results.py
set -euo pipefail
cd "$(dirname "$0")/.."
bin=.venv/bin
data=${DATA:-data/v2}
gate_data=${GATE_DATA:-$data/gate}
paper_run=${PAPER_RUN:-runs/paper_short}
paper_steps=${PAPER_STEPS:-120}
read -r -a checkpoints <<< "${CHECKPOINTS:-models/msfsu_default.pt models/msf.pt models/su.pt $paper_run/best.pt}"

# 1. the data: training bags (calibration, the paper run), validation bags (recipe ranking), held-out gate bags
if ! compgen -G "$data/train/*" >/dev/null || ! compgen -G "$data/validation/*" >/dev/null; then
  $bin/msfsu-collect --output "$data" --split train --episodes 1 --max-steps 900 --workers "${WORKERS:-2}"
  $bin/msfsu-collect --output "$data" --split validation --episodes 1 --traffic regular dense --max-steps 400 \
    --no-noise --workers "${WORKERS:-2}"
fi
GATE_DATA="$gate_data" bash scripts/gate_bags.sh

# 2. a short run of the paper's network (ResNet-50 V2, 224x224): enough to compare precisions of one checkpoint.
#    One route per town x weather x traffic (index 000) and one town's validation bags keep its 224x224 cache small.
if [[ " ${checkpoints[*]} " == *" $paper_run/best.pt "* ]] && [ ! -e "$paper_run/best.pt" ]; then
  $bin/msfsu-train --train-bags "$data/train/*_000" --val-bags "$data/validation/town_a_*" \
    --preset paper --bf16 --channels-last --max-steps "$paper_steps" --num-threads 2 --out "$paper_run"
fi

# 3. per checkpoint: calibration frames (balanced over the commands), then the int8 recipe. The one-layer-in-float
#    ranking (most of the time: 105 layers of the paper network on 200 frames) is reused from the committed record
#    when it measured this very checkpoint and exported graph (msfsu-int8-recipe refuses one of other calibration or validation frames)
record_name() {  # models/msf.pt -> msf, runs/paper_short/best.pt -> paper_short
  if [ "$(dirname "$1")" = models ]; then basename "$1" .pt; else basename "$(dirname "$1")"; fi
}
for checkpoint in "${checkpoints[@]}"; do
  name=$(record_name "$checkpoint")
  frames=400
  [ "$checkpoint" = "$paper_run/best.pt" ] && frames=200  # ~75 ms per int8 frame: 200 frames x 105 layers
  [ "$checkpoint.calibration.npz" -nt "$checkpoint" ] || \
    $bin/msfsu-calibrate "$checkpoint" --bags "$data/train/*" --frames 300
  record=benchmarks/int8_recipes/$name.json
  reuse=()
  if [ -e "$record" ] && $bin/python -c 'import json, sys, pathlib; from msfsu_perception import deploy_files as d
r = json.load(open(sys.argv[1]))
sys.exit((r.get("deploy_format"), r["checkpoint_digest"]) != (d.DEPLOY_FORMAT_VERSION, d.file_digest(pathlib.Path(sys.argv[2]))))' \
    "$record" "$checkpoint"; then
    reuse=(--ranking-from "$record")
  fi
  $bin/msfsu-int8-recipe "$checkpoint" --val-bags "$data/validation/*" --frames "$frames" "${reuse[@]}" \
    --out "benchmarks/int8_recipes/$name"
done

# 4. the gate on the pooled held-out bags (verdicts recorded beside each checkpoint); the paper run's records are
#    copied under benchmarks/ and docs/results/training/ (runs/ is not committed)
gate=(python benchmarks/perception.py --gate-bags "$gate_data/test/*" --record-gate --iterations 0 --e2e-frames 0)
for checkpoint in "${checkpoints[@]}"; do
  case "$checkpoint" in
    models/msfsu_default.pt) $bin/"${gate[@]}" --models cpu --cpu-checkpoint "$checkpoint" \
                               --out benchmarks/perception_gate_results.md ;;
    models/*) $bin/"${gate[@]}" --models cpu --cpu-checkpoint "$checkpoint" \
                --out "benchmarks/perception_gate_results_$(basename "$checkpoint" .pt).md" ;;
    "$paper_run/best.pt")
      $bin/"${gate[@]}" --models paper --checkpoint "$checkpoint" --out benchmarks/perception_gate_results_paper.md
      mkdir -p benchmarks/gate_records docs/results/training/paper_short
      cp "$paper_run"/{metrics.csv,loss_curves.png,args.json} docs/results/training/paper_short/
      rm -f "benchmarks/gate_records/$(basename "$paper_run")"_*  # the records of an older checkpoint or format
      for record in "$paper_run"/best.pt.deploy/*-gate.json "$paper_run"/best.pt.deploy/*-int8-recipe.json; do
        cp "$record" "benchmarks/gate_records/$(basename "$paper_run")_$(basename "$record")"
      done ;;
  esac
done

# 5. the latency table with torch eager in the same run (take it on a quiet machine: the load is printed)
if [ -e "$paper_run/best.pt" ]; then
  $bin/python benchmarks/perception.py --checkpoint "$paper_run/best.pt" --cpu-checkpoint models/msfsu_default.pt \
    --out benchmarks/perception_results.md --json benchmarks/perception_results.json
  # 6. where the int8 time goes: OpenVINO's per-layer counters, the graph as exported and as in torch
  $bin/python benchmarks/int8_profile.py "$paper_run/best.pt" models/msfsu_default.pt \
    --out benchmarks/int8_profile_results.md --json benchmarks/int8_profile_results.json
fi
