#!/usr/bin/env bash
# The default model driving the closed-loop benchmark free-running (issue 31), beside its lockstep episodes.
# The simulator steps on the wall clock at REAL_TIME_FACTOR x real time (default 0.5) with the last control that
# arrived (msfsu-benchmark --real-time-factor; CARLA's asynchronous mode), on the same 140 routes as the lockstep
# records of the shipped networks (docs/results/closed_loop/records/networks: 10 per task and condition). Then
# docs/results/free_running/ is written from both: success side by side, paired per route, the factor achieved
# and the age of the controls applied. Resumable: re-running continues where it stopped. One worker: free-running
# timing must not share the cores with a second simulator. REPORT_ONLY=1 only rewrites the reports. The probe
# report (probe_factor_1/) is of one route at factor 1, made with
#   msfsu-benchmark --checkpoint msfsu_realtime=models/msfsu_default.pt --real-time-factor 1 --suite nocrash \
#     --tasks nocrash_dense --conditions train --routes-per-task 1 --out docs/results/free_running/probe_factor_1/records/msfsu_realtime
set -euo pipefail
cd "$(dirname "$0")/.."
bin=.venv/bin
docs=docs/results/free_running
run=$docs/records/msfsu_realtime
if [ -z "${REPORT_ONLY:-}" ]; then
  $bin/msfsu-benchmark --checkpoint msfsu_realtime=models/msfsu_default.pt --real-time-factor "${REAL_TIME_FACTOR:-0.5}" \
    --suite corl2017 nocrash --conditions train heldout --routes-per-task 10 --workers 1 --out "$run"
fi
$bin/msfsu-benchmark-report docs/results/closed_loop/records/networks "$run" --agents msfsu msfsu_realtime --out "$docs"
# the probe behind the choice of 0.5: nocrash_dense train/00 at factor 1 (records committed; report only)
$bin/msfsu-benchmark-report "$docs/probe_factor_1/records/msfsu_realtime" --out "$docs/probe_factor_1"
