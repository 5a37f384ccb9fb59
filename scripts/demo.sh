#!/usr/bin/env bash
# Main job: replay a bag through bag_player -> perception -> control (each its own process),
# recording the graph's outputs next to a copy of the run's command line.
set -euo pipefail
cd "$(dirname "$0")/.."
bag=${1:-bags/sample}
checkpoint=${2:-models/msfsu_default.pt}
run_dir=${3:-runs/demo}

for needed in "$bag/metadata.yaml" "$checkpoint"; do
  if [ ! -e "$needed" ]; then
    echo "demo: $needed is missing. Give another bag/checkpoint: make demo SAMPLE_BAG=<bag dir> CHECKPOINT=<file.pt>" >&2
    exit 2
  fi
done
mkdir -p "$run_dir"
outputs="$run_dir/outputs-$(date +%Y%m%d-%H%M%S)"
.venv/bin/python -m msfsu_bringup replay --arg "bag=$bag" --arg "checkpoint=$checkpoint" --arg "record=$outputs"
echo "demo: outputs recorded in $outputs"
