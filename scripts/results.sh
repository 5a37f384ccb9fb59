#!/usr/bin/env bash
# The runs behind docs/results/: open loop (held-out bags) and the closed-loop suites for the shipped
# MSFSU, MSF and SU checkpoints and the expert. ROUTES_PER_TASK=25 is the full benchmark (~days on 2 cores);
# the committed tables say which value produced them. Resumable: re-running continues where it stopped.
# REPORT_ONLY=1 rewrites the closed-loop tables from the episodes already run (e.g. by partial runs).
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${RUNS:-runs/results}
routes_per_task=${ROUTES_PER_TASK:-25}
workers=${WORKERS:-2}
held_out_bags=(bags/sample ${TEST_BAGS:-data/sim/test/*})
bin=.venv/bin
docs=docs/results
mkdir -p "$docs/open_loop" "$docs/closed_loop"

$bin/msfsu-benchmark --checkpoint msfsu=models/msfsu_default.pt --checkpoint msf=models/msf.pt \
  --checkpoint su=models/su.pt --suite corl2017 nocrash --conditions train heldout \
  --routes-per-task "$routes_per_task" --workers "$workers" --out "$runs/closed_loop" ${REPORT_ONLY:+--report-only}
cp "$runs/closed_loop/results.md" "$runs/closed_loop/results.json" "$docs/closed_loop/"
cp "$runs/closed_loop"/*.png "$docs/closed_loop/" 2>/dev/null || true

for variant in msfsu_default msf su; do
  for bag in "${held_out_bags[@]}"; do
    out="$runs/open_loop/$variant/$(basename "$bag")"
    [ -e "$out/report.json" ] || $bin/msfsu-eval-bag "$bag" --checkpoint "models/$variant.pt" --out "$out"
    mkdir -p "$docs/open_loop/$variant"
    cp "$out/report.md" "$docs/open_loop/$variant/$(basename "$bag").md"
  done
done
$bin/python -m msfsu_evaluation.open_loop_table "$runs/open_loop" > "$docs/open_loop.md"
