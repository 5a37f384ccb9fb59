#!/usr/bin/env bash
# The accuracy gate of the shipped models and of a short paper-preset run, end to end: the data, the paper run, then
# per checkpoint `msfsu-gate` (calibration frames, int8 recipe, verdicts: docs/deployment.md), then the timings.
# Reads the data set of msfsu-default-model (DATA, default data/v2: training and validation bags, the
# held-out gate bags; it collects what is missing). Resumable: collection skips finished bags, the paper run is
# skipped once its best.pt exists, msfsu-gate keeps current calibration frames and reuses a ranking.
#   CHECKPOINTS="models/msfsu_default.pt" bash scripts/int8_gate.sh     # one model (no paper run unless listed)
# The perception tables of docs/deployment.md come from what it writes:
#   msfsu-results-blocks
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

# 3. per checkpoint, one msfsu-gate: calibration frames (balanced over the commands; rebuilt only for a checkpoint
#    newer than them), the int8 recipe (per-layer sensitivity on validation frames; the ranking of the committed
#    record is reused when it measured this very checkpoint), the verdicts on the pooled held-out bags beside the
#    checkpoint, and the gate page under benchmarks/. The paper run's records are copied under benchmarks/ and
#    docs/results/training/ (runs/ is not committed).
record_name() {  # models/msf.pt -> msf, runs/paper_short/best.pt -> paper_short
  if [ "$(dirname "$1")" = models ]; then basename "$1" .pt; else basename "$(dirname "$1")"; fi
}
for checkpoint in "${checkpoints[@]}"; do
  name=$(record_name "$checkpoint")
  frames=400 page=benchmarks/perception_gate_results_$name.md
  case "$checkpoint" in
    models/msfsu_default.pt) page=benchmarks/perception_gate_results.md ;;
    "$paper_run/best.pt") frames=200 page=benchmarks/perception_gate_results_paper.md ;;  # its layer search: the long step
  esac
  $bin/msfsu-gate "$checkpoint" --bags "$gate_data/test/*" --calibration-bags "$data/train/*" \
    --calibration-frames 300 --val-bags "$data/validation/*" --recipe-frames "$frames" \
    --recipe-out "benchmarks/int8_recipes/$name" --out "$page"
  if [ "$checkpoint" = "$paper_run/best.pt" ]; then
    mkdir -p benchmarks/gate_records docs/results/training/paper_short
    cp "$paper_run"/{metrics.csv,loss_curves.png,args.json} docs/results/training/paper_short/
    rm -f "benchmarks/gate_records/$(basename "$paper_run")"_*  # the records of an older checkpoint or format
    for record in "$paper_run"/best.pt.deploy/*-gate.json "$paper_run"/best.pt.deploy/*-int8-recipe.json; do
      cp "$record" "benchmarks/gate_records/$(basename "$paper_run")_$(basename "$record")"
    done
  fi
done

# 4. the latency table with torch eager in the same run (take it on a quiet machine: the load is printed)
if [ -e "$paper_run/best.pt" ]; then
  $bin/python benchmarks/perception.py --checkpoint "$paper_run/best.pt" --cpu-checkpoint models/msfsu_default.pt \
    --out benchmarks/perception_results.md --json benchmarks/perception_results.json
  # 5. where the int8 time goes: OpenVINO's per-layer counters, the graph as exported and as in torch
  $bin/python benchmarks/int8_profile.py "$paper_run/best.pt" models/msfsu_default.pt \
    --out benchmarks/int8_profile_results.md --json benchmarks/int8_profile_results.json
fi
