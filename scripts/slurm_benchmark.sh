#!/usr/bin/env bash
# msfsu-benchmark as a SLURM array job: array task K of N runs shard K/N of the suite into its own
# directory; the report merges the shards (merging is concatenating their episode records).
#
#   sbatch --array=1-8 scripts/slurm_benchmark.sh --checkpoint msfsu=models/msfsu_default.pt --suite all
#   .venv/bin/msfsu-benchmark-report runs/bench/shard-* --out runs/bench/report
#
# Array ids must run 1..N. Arguments go to msfsu-benchmark; BENCH_OUT (default runs/bench) is where the
# shard directories go. A task that was cut off resumes when resubmitted with the same array id.
#SBATCH --job-name=msfsu-benchmark
#SBATCH --cpus-per-task=2
#SBATCH --mem=8G
#SBATCH --time=08:00:00
set -euo pipefail
cd "${SLURM_SUBMIT_DIR:-$(dirname "$0")/..}"
index=${SLURM_ARRAY_TASK_ID:?run it as an array job: sbatch --array=1-N $0 ...}
count=${SLURM_ARRAY_TASK_COUNT:?run it as an array job: sbatch --array=1-N $0 ...}
exec .venv/bin/msfsu-benchmark --shard "$index/$count" --out "${BENCH_OUT:-runs/bench}/shard-$index" "$@"
