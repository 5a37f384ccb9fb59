#!/usr/bin/env bash
# The runs behind docs/results/, then the reports regenerated from their records. Resumable: re-running
# continues where it stopped (finished episodes and bag reports are kept).
#   closed loop (routes v3, current simulator revision): the expert on the full suites (every task, both
#     conditions, 25 routes each) into docs/results/closed_loop_v3_rev4/records/expert; with NETWORKS=1 the expert
#     and the shipped MSFSU, MSF and SU on the node's default backend and precision, and MSFSU in fp32 (msfsu_fp32),
#     on the first NETWORK_ROUTES (25: all) routes of every cell, through the current node graph revision, into
#     docs/results/closed_loop_v3_graph2/records/networks. WORKERS simulators (default 1).
#   DAgger (DAGGER=1): each round's MSFSU at the round's last epoch (RUNS/msfsu/round<N>.last.pt of
#     msfsu-default-model) and the same-budget branch without round N's data at the same epoch
#     (RUNS/msfsu_branch<N>/last.pt, BRANCH=1 there: agent branch<N>) on the first
#     DAGGER_ROUTES (25: the whole cells, 75 routes paired) training-condition routes of the traffic tasks, into
#     docs/results/dagger_v3/records/msfsu (held-out routes never choose anything).
#   open loop: the shipped models on the held-out bags (bags/sample and TEST_BAGS).
# Reports only, from their committed records (never run again): routes v2 (docs/results/closed_loop/, dagger/) and
# routes v3 on simulator revision 3 (docs/results/closed_loop_v3/: a run directory never mixes revisions).
# REPORT_ONLY=1 skips every run and only rewrites the reports from the records there.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=.venv/bin
docs=docs/results
records_rev3=$docs/closed_loop_v3/records  # simulator revision 3: complete, reported only
current=$docs/closed_loop_v3_rev4  # the current revision (msfsu_sim.SIMULATOR_REVISION)
records=$current/records  # the expert and the v2 MSFSU through node graph revision 1
graph2=$docs/closed_loop_v3_graph2  # the shipped networks through node graph revision 2 (msfsu_bringup.GRAPH_REVISION)
workers=${WORKERS:-1}
held_out_bags=(bags/sample ${TEST_BAGS:-data/v2/gate/test/*})
runs=${RUNS:-runs/v2}
mkdir -p "$docs/open_loop" "$records"

if [ -z "${REPORT_ONLY:-}" ]; then
  $bin/msfsu-benchmark --agent expert --suite corl2017 nocrash --conditions train heldout \
    --workers "$workers" --out "$records/expert"
  if [ -n "${NETWORKS:-}" ]; then
    $bin/msfsu-benchmark --checkpoint msfsu=models/msfsu_default.pt --checkpoint msf=models/msf.pt \
      --checkpoint su=models/su.pt --checkpoint msfsu_fp32=models/msfsu_default.pt --precision msfsu_fp32=fp32 \
      --suite corl2017 nocrash --conditions train heldout \
      --routes-per-task "${NETWORK_ROUTES:-25}" --workers "$workers" --out "$graph2/records/networks"
  fi
  if [ -n "${DAGGER:-}" ]; then
    # Each round at its last epoch, not its best (roundN.pt): the best is chosen on the validation frames the expert
    # drove, which carry none of the on-policy states a DAgger round adds: a round's best can be an epoch of the round
    # before, and the round would be compared with itself. The last epochs of a round and of its branch had the same
    # data budget and steps, and nothing chose between them.
    rounds=()
    for model in "$runs"/msfsu/round*.last.pt; do
      [[ $(basename "$model") =~ ^round([0-9]+)\.last\.pt$ ]] && rounds+=(--checkpoint "round${BASH_REMATCH[1]}=$model")
    done
    for model in "$runs"/msfsu_branch*/last.pt; do  # a branch directory holds one round: msfsu_branch<N>
      [[ $model =~ msfsu_branch([0-9]+)/last\.pt$ ]] && rounds+=(--checkpoint "branch${BASH_REMATCH[1]}=$model")
    done
    $bin/msfsu-benchmark "${rounds[@]}" --suite corl2017 nocrash --conditions train \
      --tasks navigation_dynamic nocrash_regular nocrash_dense --routes-per-task "${DAGGER_ROUTES:-25}" \
      --workers "$workers" --out "$docs/dagger_v3/records/msfsu"
  fi
fi
# the expert drove its routes in its own run and beside the networks: its own run's records make its row
for records_dir in "$records_rev3" "$records"; do  # (graph 2's report: below)
  if [ -d "$records_dir/expert" ]; then
    prefer=()
    [ -d "$records_dir/networks" ] && prefer=(--prefer expert="$records_dir/expert")
    $bin/msfsu-benchmark-report "$records_dir"/*/ "${prefer[@]}" --out "$(dirname "$records_dir")"
  fi
done
# what the current revision changed, per agent driven on both (the expert; the v2 MSFSU as msfsu_v2)
if [ -d "$records/expert" ]; then
  $bin/python scripts/revision_change.py "$records_rev3/expert:expert" "$records/expert:expert" \
    --out "$current/revision_change_expert.md" > /dev/null
fi
if [ -d "$records/msfsu_v2" ]; then
  $bin/python scripts/revision_change.py "$records_rev3/networks:msfsu" "$records/msfsu_v2:msfsu_v2" \
    --out "$current/revision_change_msfsu_v2.md" > /dev/null
fi
# the shipped networks through node graph revision 2, and what the graph change did to each: MSFSU beside its graph-1
# run on the same simulator revision and machine (msfsu_v2); MSF and SU beside their graph-1 runs, which were on
# simulator revision 3 and another machine (the only graph-1 records of them)
if [ -d "$graph2/records/networks" ]; then
  $bin/msfsu-benchmark-report "$graph2"/records/*/ --out "$graph2"
  declare -A graph1_of=([msfsu]="$records/msfsu_v2:msfsu_v2" [msf]="$records_rev3/networks:msf" [su]="$records_rev3/networks:su")
  changed=()
  for agent in msfsu msf su; do
    if grep -q "\"agent\": \"$agent\"" "$graph2/records/networks/episodes.jsonl"; then
      $bin/python scripts/revision_change.py "${graph1_of[$agent]}" "$graph2/records/networks:$agent" \
        --out "$graph2/graph_change_$agent.md" > /dev/null
      changed+=("$agent" "${graph1_of[$agent]}" "$graph2/records/networks:$agent")
    fi
  done
  # every network's before/after in one table
  if [ ${#changed[@]} -gt 0 ]; then
    $bin/python scripts/graph_change_table.py "${changed[@]}" --out "$graph2/graph_change.md" > /dev/null
  fi
fi
v2=$docs/closed_loop/records
$bin/msfsu-benchmark-report "$v2"/*/ --prefer expert="$v2/expert" --out "$docs/closed_loop"
for dagger in "$docs"/dagger "$docs"/dagger_v3; do
  if [ -d "$dagger/records" ]; then
    $bin/msfsu-benchmark-report "$dagger"/records/*/ --out "$dagger"
  fi
done
# each run directory's own page again from the records it names (the reports above were just written; the free-running
# ones are scripts/free_running.sh's)
$bin/msfsu-regenerate-reports --run-pages > /dev/null

for variant in msfsu_default msf su; do
  for bag in "${held_out_bags[@]}"; do
    [ -e "$bag" ] || continue
    out="runs/results/open_loop/$variant/$(basename "$bag")"
    [ -n "${REPORT_ONLY:-}" ] || [ -e "$out/report.json" ] || \
      $bin/msfsu-eval-bag "$bag" --checkpoint "models/$variant.pt" --out "$out"
    if [ -e "$out/report.md" ]; then
      mkdir -p "$docs/open_loop/$variant"
      cp "$out/report.md" "$docs/open_loop/$variant/$(basename "$bag").md"
    fi
  done
done
if [ -d runs/results/open_loop ]; then
  $bin/python -m msfsu_evaluation.open_loop_table runs/results/open_loop > "$docs/open_loop.md"
fi
