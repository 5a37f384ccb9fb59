#!/usr/bin/env bash
# The held-out bags the accuracy gate scores (issue #14): one command, deterministic (fixed towns, weathers,
# traffic, episode lengths and base seed), resumable (finished bags are skipped). The held-out towns x weathers
# with regular and dense traffic, without steering noise (every frame has a clean expert label), long enough to
# drive through each town's junctions: town_h1's route turns LEFT twice 390-480 m in (after a STRAIGHT crossing),
# so 75 s; town_h2's turns RIGHT at 230 m and ends at 350 m, so 40 s. An episode the expert ends in a collision is
# dropped by msfsu-collect (listed in <out>/dropped.jsonl); the gate records which bags and frames it pooled.
#   bash scripts/gate_bags.sh            # -> data/gate/test/<town>_<weather>_<traffic>_000
#   GATE_DATA=data/lateral SEED=15 EPISODES=2 bash scripts/gate_bags.sh   # more held-out episodes of the same kind
set -euo pipefail
cd "$(dirname "$0")/.."
out=${GATE_DATA:-data/gate}
collect=(.venv/bin/msfsu-collect --output "$out" --split test --weathers soft_rain_dusk foggy_day
         --traffic regular dense --episodes "${EPISODES:-1}" --seed "${SEED:-14}" --no-noise --workers "${WORKERS:-1}")
"${collect[@]}" --towns town_h1 --max-steps 750
"${collect[@]}" --towns town_h2 --max-steps 400
