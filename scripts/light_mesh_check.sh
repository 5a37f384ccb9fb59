#!/usr/bin/env bash
# Does the network see a difference between MetaDrive's full traffic models and the light meshes?
# The same held-out episodes (towns, weathers, traffic, seed: the expert drives the same way, the simulator
# state does not depend on what is drawn) are recorded twice, once with each, and the default model is
# evaluated open loop on both sets (msfsu-eval-bag, the real node graph). Resumable: finished bags and
# reports are kept. The table goes to docs/results/light_meshes.md.
#   DATA=data/light_mesh_check RUNS=runs/light_mesh_check bash scripts/light_mesh_check.sh
set -euo pipefail
cd "$(dirname "$0")/.."
bin=.venv/bin
data=${DATA:-data/light_mesh_check}
runs=${RUNS:-runs/light_mesh_check}
checkpoint=${CHECKPOINT:-models/msfsu_default.pt}
seed=${SEED:-7100}  # not a seed the shipped models' data used (msfsu-default-model)

for meshes in full light; do
  flag=()
  [ "$meshes" = full ] && flag=(--full-meshes)
  $bin/msfsu-collect --output "$data/$meshes" --split test --traffic regular dense --seed "$seed" "${flag[@]}"
done
for meshes in full light; do
  for bag in "$data/$meshes"/test/*/; do
    bag=${bag%/}
    out="$runs/$meshes/$(basename "$bag")"
    [ -e "$out/report.json" ] || $bin/msfsu-eval-bag "$bag" --checkpoint "$checkpoint" --out "$out"
  done
done
{
  echo "# Light meshes, open loop: the default model on the same held-out episodes drawn both ways"
  echo
  echo "\`bash scripts/light_mesh_check.sh\` (seed $seed, \`$checkpoint\`): \`full\` = MetaDrive's traffic and"
  echo "pedestrian models, \`light\` = the light meshes (msfsu_sim.light_meshes). Same routes, same expert drive."
  echo
  $bin/python -m msfsu_evaluation.open_loop_table "$runs"
} > docs/results/light_meshes.md
cat docs/results/light_meshes.md
