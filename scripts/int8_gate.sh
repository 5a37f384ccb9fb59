#!/usr/bin/env bash
# Issue #14 end to end: the data, a short paper-preset run, calibration frames, int8 recipes (per-layer
# sensitivity on validation frames) and gate verdicts on the pooled held-out bags. Resumable: collection skips
# finished bags, training is skipped once its best.pt exists, calibration once its file exists.
# About 3 h on 2 cores. The README's perception tables come from what the last step writes:
#   python scripts/readme_results.py
set -euo pipefail
cd "$(dirname "$0")/.."
bin=.venv/bin
data=${DATA:-data/v2}  # scripts/default_model.sh collects the same data set (its bags are reused)
gate_data=${GATE_DATA:-$data/gate}
paper_run=${PAPER_RUN:-runs/paper_short}
paper_steps=${PAPER_STEPS:-120}

# 1. training bags (int8 calibration, the paper run), validation bags (recipe ranking, the run's validation),
#    the gate's held-out bags (scripts/gate_bags.sh)
$bin/msfsu-collect --output "$data" --split train --episodes 1 --traffic empty regular dense --max-steps 200 --workers 1
# ... 20 s reach a junction only in town_a (LEFT): a second, 32 s episode per weather in town_b (RIGHT) and town_c
# (STRAIGHT), so the calibration frames hold every command
$bin/msfsu-collect --output "$data" --split train --towns town_b town_c --episodes 2 --traffic regular --max-steps 320 \
  --workers 1
$bin/msfsu-collect --output "$data" --split validation --episodes 1 --weathers wet_cloudy --traffic regular dense \
  --max-steps 250 --no-noise --workers 1
GATE_DATA="$gate_data" bash scripts/gate_bags.sh

# 2. a short run of the paper's network (ResNet-50 V2, 224x224): enough to compare precisions of one checkpoint
[ -e "$paper_run/best.pt" ] || $bin/msfsu-train --train-bags "$data/train/*" --val-bags "$data/validation/*" \
  --preset paper --bf16 --channels-last --max-steps "$paper_steps" --num-threads 2 --out "$paper_run"

# 3. per checkpoint: calibration frames (balanced over the commands), then the int8 recipe. The one-layer-in-float
#    ranking (most of the time: 105 layers of the paper network on 200 frames) is reused from the committed record
#    when it measured this very checkpoint (msfsu-int8-recipe refuses one of other calibration or validation frames)
for checkpoint in models/msfsu_default.pt models/msf.pt models/su.pt "$paper_run/best.pt"; do
  name=$(basename "$(dirname "$checkpoint")")_$(basename "$checkpoint" .pt)
  [ "$(dirname "$checkpoint")" = models ] && name=$(basename "$checkpoint" .pt)
  frames=400
  [ "$checkpoint" = "$paper_run/best.pt" ] && frames=200  # ~75 ms per int8 frame: 200 frames x 105 layers
  [ -e "$checkpoint.calibration.npz" ] || $bin/msfsu-calibrate "$checkpoint" --bags "$data/train/*" --frames 300
  record=benchmarks/int8_recipes/$name.json
  reuse=()
  if [ -e "$record" ] && $bin/python -c 'import json, sys, pathlib; from msfsu_perception.deploy_files import file_digest
sys.exit(json.load(open(sys.argv[1]))["checkpoint_digest"] != file_digest(pathlib.Path(sys.argv[2])))' "$record" "$checkpoint"; then
    reuse=(--ranking-from "$record")
  fi
  $bin/msfsu-int8-recipe "$checkpoint" --val-bags "$data/validation/*" --frames "$frames" "${reuse[@]}" \
    --out "benchmarks/int8_recipes/$name"
done

# 4. the gate on the pooled held-out bags (verdicts recorded beside each checkpoint); the paper run's record is
#    copied under benchmarks/ (runs/ is not committed)
gate=(python benchmarks/perception.py --gate-bags "$gate_data/test/*" --record-gate --iterations 0 --e2e-frames 0)
$bin/"${gate[@]}" --models cpu --cpu-checkpoint models/msfsu_default.pt --out benchmarks/perception_gate_results.md
$bin/"${gate[@]}" --models cpu --cpu-checkpoint models/msf.pt --out benchmarks/perception_gate_results_msf.md
$bin/"${gate[@]}" --models cpu --cpu-checkpoint models/su.pt --out benchmarks/perception_gate_results_su.md
$bin/"${gate[@]}" --models paper --checkpoint "$paper_run/best.pt" --out benchmarks/perception_gate_results_paper.md
mkdir -p benchmarks/gate_records
for record in "$paper_run"/best.pt.deploy/*-gate.json "$paper_run"/best.pt.deploy/*-int8-recipe.json; do
  cp "$record" "benchmarks/gate_records/$(basename "$paper_run")_$(basename "$record")"
done

# 5. the latency table with torch eager in the same run (take it on a quiet machine: the load is printed)
$bin/python benchmarks/perception.py --checkpoint "$paper_run/best.pt" --cpu-checkpoint models/msfsu_default.pt \
  --out benchmarks/perception_results.md --json benchmarks/perception_results.json
