#!/usr/bin/env bash
# Model v3 (issue 58): the shipped v2 models trained further on this machine's budget, in stages of at most ~2.5 h,
# each stage's product committed when it ends (docs/training.md, "Model v3": the plan, its hours, the levers).
#
#   bash scripts/model_v3.sh                 every stage not yet done, in order
#   bash scripts/model_v3.sh STAGE...        these stages only (data-expert data-dagger train-msfsu train-su
#                                            train-msf judge-msfsu judge-msf-su release)
#   COMMIT=1 bash scripts/model_v3.sh        also `git commit` each stage's product (and only it) when it ends
#
# A stage is done when its committed product exists: its line in docs/results/model_v3/stages.jsonl (the stage's
# wall hours, machine and command; docs/training.md shows them beside the plan's, docs/results/model_v3/plan.json).
# Data stages re-run when their bags are gone (a new machine): the recipe is deterministic, so msfsu-collect writes
# the same bags again, and the first measurement of the stage stays the record.
# A training stage resumes from its run's last.pt; without it (a new machine) from its snapshot, committed after every
# epoch (checkpoints/v3/progress/<run>: fp16 weights, run and schedule state, metrics; a fresh optimizer), else from
# the start: the weights it starts from (models/*.pt, the shipped v2) are committed. A lost machine costs an epoch.
# A benchmark stage resumes from its committed episodes.
# A submission takes at most 256 MiB of diffs (git's binary patches: a changed 28 MB checkpoint counts ~68 MB), so the
# snapshot commits of a stage are one commit, amended after every epoch while no other commit follows it, and one that
# would take the unsubmitted commits past PROGRESS_LIMIT_MIB is not made (the snapshot stays on disk; the log says so).
# The unsubmitted commits start after the branch's first reflog entry (the checkout's start); on a checkout that
# outlives a landed submission, SUBMIT_BASE=<the commit that landed> says where they start (the log's first line
# with COMMIT names the base and the MiB counted).
#
# The recipe, the same for the three variants (the ablation compares networks):
#   data-expert  round 0 as the v2 recipe collects it (the same episodes, seeds and noise): 3 routes per training
#                town x weather x traffic, and the validation bags
#   data-dagger  one on-policy round: the shipped MSFSU (models/msfsu_default.pt) drives each step the expert does not
#                (beta: the expert drives a step with probability BETA), the expert labels every frame; DAGGER_EPISODES
#                routes per town x weather x traffic
#   train-V      warm start from the shipped model of variant V with a fresh optimizer and schedule, on both rounds,
#                the on-policy focus frames (crash approaches, near misses) FOCUS_COPIES more times, EPOCHS epochs
#                under the cosine schedule (one recipe, so within 1 % the same steps, for every variant); its best
#                validation checkpoint in fp16 is checkpoints/v3/V.pt, the count of the bags it trained on, then its
#                accuracy gate (while the bags are on the machine)
#   judge-*      benchmark v3 (routes v3, 350 routes per network; the expert beside MSFSU) of the v3 checkpoints (a
#                checkpoint not yet gated is gated first, on bags collected for it), and
#                their pages: the report of every judged run, each v3 network paired with its shipped v2 (v3_change.md)
#   release      the release rule (msfsu-model-v3-release): models/ takes the v3 models only if v3 MSFSU beats
#                the shipped one, paired over the 350 routes
set -euo pipefail
cd "$(dirname "$0")/.."
data=${DATA:-data/v3}
runs=${RUNS:-runs/v3}
workers=${WORKERS:-2}
beta=${BETA:-0.25}
dagger_episodes=${DAGGER_EPISODES:-2}
epochs=${EPOCHS:-4}  # of the two rounds' ~2,510 batches: ~10,040 steps, per epoch down a cosine from 3e-4
progress_limit_mib=${PROGRESS_LIMIT_MIB:-160}  # of a submission's 256: room left for a stage's product
focus_copies=${FOCUS_COPIES:-3}
record=${RECORD:-docs/results/model_v3}
checkpoints=${CHECKPOINTS:-checkpoints/v3}
judged=${JUDGED:-docs/results/closed_loop_v3_model_v3/records}
report=${REPORT:-docs/results/closed_loop_v3_model_v3}
baseline=${BASELINE:-docs/results/closed_loop_v3_graph2/records/networks}  # the shipped models on today's graph
bin=.venv/bin
stages_file=$record/stages.jsonl
declare -A shipped=([msfsu]=models/msfsu_default.pt [msf]=models/msf.pt [su]=models/su.pt)
all_stages=(data-expert data-dagger train-msfsu train-su train-msf judge-msfsu judge-msf-su release)

step() { echo "[model-v3 $(date -u +%Y-%m-%dT%H:%M:%SZ)] $*"; }
done_already() { [ -f "$stages_file" ] && grep -q "\"stage\": \"$1\"" "$stages_file"; }

# A stage's wall time over every invocation (a session's end stops a stage; the next one resumes it): each invocation
# keeps a file $record/clock/<stage>/<its start, epoch s> holding the last second it was seen alive (a heartbeat every
# 30 s while this script runs), committed with the stage's progress, so that the hours spent on a lost machine count.
# Bags collected again on a new machine count under the clock "re-collect". While $runs/clock.hold exists the
# heartbeat waits (a progress commit regenerates the hours' blocks from the clocks and commits both as they are).
clock=$record/clock
hold=$runs/clock.hold
mkdir -p "$runs"  # where the hold is made (the committer's first look may come before msfsu-train makes its --out)
clock_start() {
  local file
  started=$(date +%s) clocked=$1
  file="$clock/$1/$started"
  mkdir -p "$(dirname "$file")"
  echo "$started" > "$file"
  ( while kill -0 $$ 2>/dev/null; do
      [ -e "$hold" ] || { date +%s > "$file.new" && mv -f "$file.new" "$file"; }
      sleep 30
    done ) \
    > /dev/null 2>&1 &
  heartbeat=$!
}
trap 'kill "${heartbeat:-}" 2>/dev/null || true' EXIT

# the running clock's invocation ends now
clock_stop() {
  kill "$heartbeat" 2>/dev/null || true
  wait "$heartbeat" 2>/dev/null || true
  date +%s > "$clock/$clocked/$started"
}

# the pages with generated blocks (the stages' hours, the gate's table...), regenerated: what a commit takes with them
generated_pages() { $bin/msfsu-results-blocks > /dev/null && $bin/msfsu-results-blocks --list; }

# $1 stage, $2... the stage's product paths: the stage's record line (its hours over every invocation), then the commit
finish() {
  local stage=$1 ended; shift
  ended=$(date +%s)
  clock_stop
  mkdir -p "$record"
  if ! done_already "$stage"; then
    $bin/python - "$stage" "$clock/$stage" "$stages_file" <<'EOF'
import os, platform, subprocess, sys
from pathlib import Path
from msfsu_evaluation.records.stages import StageRecord, clock_hours
stage, clock, path = sys.argv[1], Path(sys.argv[2]), sys.argv[3]
runs = {int(f.name): int(f.read_text()) for f in clock.iterdir() if f.name.isdigit()}  # start -> last seen alive
cpu = next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")),
           platform.processor())
commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
record = StageRecord(stage=stage, started_utc=min(runs), ended_utc=max(runs.values()), invocations=len(runs),
                     hours=round(clock_hours(clock), 3),
                     machine=f"{cpu}, {len(os.sched_getaffinity(0))} CPUs", code=commit)
with open(path, "a") as stream:
    stream.write(record.to_line() + "\n")
EOF
  fi
  local pages
  mapfile -t pages < <(generated_pages)  # the stage's hours into docs/training.md (its model-v3-stages block)
  step "stage $stage done ($(( (ended - started) / 60 )) min in this invocation)"
  if [ -n "${COMMIT:-}" ]; then
    git add -- "$stages_file" "${pages[@]}" "$clock" "$@"
    # a re-run may change nothing
    git diff --cached --quiet -- "$stages_file" "${pages[@]}" "$clock" "$@" ||
      git commit -q -m "Model v3, stage $stage: its product and hours (scripts/model_v3.sh)" -- "$stages_file" \
        "${pages[@]}" "$clock" "$@"
    local size
    size=$(unsubmitted_mib)
    [ "$size" -le 256 ] || step "WARNING: the unsubmitted commits have $size MiB of diffs, over the 256 MiB a" \
      "submission takes: squash the snapshot commits before the session ends"
  fi
}

collect_expert() {
  $bin/msfsu-collect --output "$data" --split train --episodes 3 --max-steps 900 --workers "$workers"
  $bin/msfsu-collect --output "$data" --split validation --episodes 1 --traffic regular dense --max-steps 400 \
    --no-noise --workers "$workers"
  GATE_DATA="$data/gate" WORKERS="$workers" bash scripts/gate_bags.sh  # the held-out bags of the accuracy gate
}

collect_dagger() {
  $bin/msfsu-collect --output "$data" --split train --episodes "$dagger_episodes" --max-steps 900 --workers "$workers" \
    --driver "${shipped[msfsu]}" --beta "$beta" --round 1
}

# $1 stage, $2 collection function: runs it (msfsu-collect skips the bags it has), records the first measurement
bags() { { find "$data" -name metadata.yaml 2>/dev/null || true; } | wc -l; }
data_stage() {
  local before
  before=$(bags)
  if done_already "$1"; then clock_start re-collect; else clock_start "$1"; fi
  step "stage $1: collection into $data"
  "$2"
  # the data report: of a new stage, or of bags collected again (on a new machine: a network's route may differ) once
  # the last data stage has them (the expert round's alone would replace the report of both rounds)
  if ! done_already "$1" || { [ "$(bags)" != "$before" ] && { [ "$1" = data-dagger ] || ! done_already data-dagger; }; }
  then
    $bin/msfsu-dataset-report "$data" --out "$record"
  fi
  finish "$1" "$record/data.json" "$record/data.md"
}

# The commits not yet submitted start after $SUBMIT_BASE, else after the commit the branch's reflog begins at (the
# checkout's start: what had landed); their diffs as a submission counts them, in MiB (git's binary patches)
submit_base() {
  echo "${SUBMIT_BASE:-$(git reflog show --format=%H "$(git symbolic-ref -q --short HEAD)" | tail -n 1)}"
}
unsubmitted_mib() { echo $(( $(git log -p --binary --format= "$(submit_base)..HEAD" | wc -c) / 1048576 )); }

# $1 stage, $2 what it commits (the commit's subject), $3 its directory: commits the directory, the clocks and the
# hours' blocks they make, as one commit per stage and kind (amended while it is the newest and not submitted);
# undone when it takes the unsubmitted diffs past PROGRESS_LIMIT_MIB. Returns 1 when the commit failed, 2 when it
# was undone.
commit_stage_progress() {
  local subject="Model v3, stage $1: $2 (scripts/model_v3.sh)" before amend=() paths=() size
  mapfile -t paths < <(generated_pages) && [ ${#paths[@]} -gt 0 ] || return 1
  paths+=("$3" "$clock")
  before=$(git rev-parse HEAD)
  if [ "$(git log -1 --format=%s)" = "$subject" ] && ! git merge-base --is-ancestor HEAD "$(submit_base)"; then
    amend=(--amend)
  fi
  git add -- "${paths[@]}" && git commit -q "${amend[@]}" -m "$subject" -- "${paths[@]}" || return 1
  size=$(unsubmitted_mib)
  if [ "$size" -gt "$progress_limit_mib" ]; then
    git reset -q --soft "$before" && git reset -q -- "${paths[@]}"
    step "stage $1: $2 not committed: the unsubmitted commits would have $size MiB of diffs (limit" \
      "$progress_limit_mib MiB, PROGRESS_LIMIT_MIB); it stays in $3"
    return 2
  fi
}

# With COMMIT, until this script ends or stop_committer: $1 stage, $2 what, $3 directory, $4 the file whose change
# means progress, $5 seconds between looks, $6 seconds it must have been still (its writer done);
# commit_stage_progress after each change, and once more when stopped (the last epoch's snapshot). A failed commit
# (another git command held the index) is tried again at the next look.
commit_progress() {
  local seen="" changed status stopping=0 waited
  set +e  # a loop beside the stage: a failed command is tried again at the next look, never its end
  trap 'stopping=1' TERM  # stop_committer's: a commit in progress, and its check, end first
  while (( ! stopping )) && kill -0 $$ 2>/dev/null; do
    for (( waited = 0; waited < $5 && ! stopping; waited++ )); do  # a look every $5 s; a stop within a second
      read -r -t 1 <> <(:) || true  # a sleep without a child that would hold the log's pipe
    done
    [ -f "$4" ] || continue
    changed=$(stat -c %Y "$4")
    if [ "$changed" != "$seen" ] && { (( stopping )) || [ $(( $(date +%s) - changed )) -ge "$6" ]; }; then
      touch "$hold"
      status=0
      commit_stage_progress "$1" "$2" "$3" || status=$?
      [ "$status" = 1 ] || seen=$changed
      rm -f "$hold"
    fi
  done
}
poll=${PROGRESS_POLL_S:-60}

# stops a commit_progress ($1, if any) once the commit it may be making is made and checked, and its last look
stop_committer() {
  [ -n "$1" ] || return 0
  kill -TERM "$1" 2>/dev/null || true
  wait "$1" 2>/dev/null || true
}

# $1 stage, $2 variant, $3 run name, $4... extra msfsu-train arguments
train_stage() {
  local stage=$1 variant=$2 name=$3 resume=() snapshots committer=""; shift 3
  snapshots=$checkpoints/progress/$name
  clock_start re-collect
  collect_expert && collect_dagger  # on a new machine the bags are collected again (the same ones); else nothing to do
  clock_stop
  rm -f "$hold"  # a stopped invocation's
  clock_start "$stage"
  if [ -n "${COMMIT:-}" ]; then
    # after every epoch (last.pt still for a third of a look: the epoch's files are all written)
    commit_progress "$stage" "the snapshot after an epoch" "$snapshots" "$snapshots/last.pt" "$poll" $(( poll / 3 )) \
      2> /dev/null &  # its lines to the log
    committer=$!
  fi
  [ -e "$runs/$name/last.pt" ] || [ -e "$snapshots/last.pt" ] && resume=(--resume)
  step "stage $stage: $variant from ${shipped[$variant]}, $epochs epochs${resume:+ (resumed)}"
  $bin/msfsu-train --train-bags "$data/train/*" --val-bags "$data/validation/*" --preset cpu --variant "$variant" \
    --init-from "${shipped[$variant]}" --epochs "$epochs" --num-threads 2 \
    --schedule cosine --focus-copies "$focus_copies" --out "$runs/$name" --snapshots "$snapshots" --evict-caches \
    "${resume[@]}" "$@"
  stop_committer "$committer"
  cp "$snapshots/best.pt" "$checkpoints/$name.pt.new"  # the best validation loss's weights in fp16, over every machine
  mv -f "$checkpoints/$name.pt.new" "$checkpoints/$name.pt"
  mkdir -p "docs/results/training/v3_$name"
  cp "$runs/$name/metrics.csv" "$runs/$name/loss_curves.png" "$runs/$name/balancing.png" "$runs/$name/args.json" \
    "docs/results/training/v3_$name/"
  # the bags it trained on, counted (data.json, data.md): an on-policy round collected again on another CPU is not
  # record for record the first (the driving network's float results differ, and the route follows them)
  $bin/msfsu-dataset-report "$data" --out "docs/results/training/v3_$name"
  gate "$stage" "$checkpoints/$name.pt"  # in the stage's hours
  # not the snapshot again: its commit stands (a commit beside it would count its 2 x 28 MB again), the stage is done
  finish "$stage" "$checkpoints/$name.pt" "docs/results/training/v3_$name"
}

# The judged runs' report (results.md: the networks, the expert beside them, against the paper) and each v3 network
# paired per route with the shipped model it started from, on the baseline's routes: v3_change.md (every network's
# suites and conditions) and v3_change_<network>.md (every route and flip)
judged_agents=(msfsu_v3=msfsu msf_v3=msf su_v3=su)  # v3 agent=the shipped agent it started from
v3_pages() {
  local judged_runs=() expert_runs=() prefer=() run pair agent shipped_agent changed=()
  for run in "$judged"/*/; do judged_runs+=("${run%/}"); done
  # the expert drives in judge-msfsu only (--no-expert elsewhere; the same simulator, so the same episodes); where
  # several runs hold it, the first one's records are its
  for run in "${judged_runs[@]}"; do
    if grep -q '"agent": "expert"' "$run/episodes.jsonl"; then expert_runs+=("$run"); fi
  done
  [ ${#expert_runs[@]} -lt 2 ] || prefer=(--prefer expert="${expert_runs[0]}")
  $bin/msfsu-benchmark-report "${judged_runs[@]}" "${prefer[@]}" --out "$report"
  for pair in "${judged_agents[@]}"; do
    agent=${pair%=*} shipped_agent=${pair#*=}
    for run in "${judged_runs[@]}"; do
      grep -q "\"agent\": \"$agent\"" "$run/episodes.jsonl" || continue
      $bin/python scripts/revision_change.py "$baseline:$shipped_agent" "$run:$agent" \
        --out "$report/v3_change_$agent.md" > /dev/null
      changed+=("$agent" "$baseline:$shipped_agent" "$run:$agent")
    done
  done
  if [ ${#changed[@]} -gt 0 ]; then
    $bin/python scripts/graph_change_table.py "${changed[@]}" --labels v2 v3 --pages "v3_change_<network>.md" \
      --out "$report/v3_change.md" > /dev/null
  fi
}

# $1 stage, $2 checkpoint: its accuracy gate as the shipped models had theirs (calibration frames, int8 recipe,
# verdicts beside it), so that it drives on the precision the perception node deploys it on (precision auto), as the
# shipped models in the baseline did; on the bags (collected here if missing), unless its verdicts exist. With COMMIT
# the gate's records are committed (not the converted models: .gitignore).
gate() {
  local stage=$1 checkpoint=$2 name products pages
  name=$(basename "$checkpoint" .pt)
  # the int8 recipe's --recipe-out is a prefix: PREFIX.json and PREFIX.md
  products=("$checkpoint.calibration.npz" "$checkpoint.deploy" "benchmarks/int8_recipes/v3_$name.json"
    "benchmarks/int8_recipes/v3_$name.md" "benchmarks/perception_gate_results_v3_$name.md")
  [ -e "benchmarks/perception_gate_results_v3_$name.md" ] && return
  collect_expert
  step "stage $stage: accuracy gate of $checkpoint"
  $bin/msfsu-gate "$checkpoint" --bags "$data/gate/test/*" --calibration-bags "$data/train/*" \
    --calibration-frames 300 --val-bags "$data/validation/*" --recipe-frames 400 \
    --recipe-out "benchmarks/int8_recipes/v3_$name" --out "benchmarks/perception_gate_results_v3_$name.md"
  if [ -n "${COMMIT:-}" ]; then  # with the gate's table (docs/deployment.md)
    mapfile -t pages < <(generated_pages)
    products+=("${pages[@]}")
    git add -- "${products[@]}"
    git commit -q -m "Model v3, stage $stage: the accuracy gate of $checkpoint (scripts/model_v3.sh)" \
      -- "${products[@]}"
  fi
}

# $1 stage, $2 "expert" to drive the expert beside the networks or "no-expert" (another judge stage drives it), $3...
# NAME=CHECKPOINT of the networks to drive, each gated first (gate).
judge_stage() {
  local stage=$1 arguments=() checkpoint committer=""; shift
  [ "$1" = expert ] || arguments+=(--no-expert)
  shift
  clock_start "$stage"
  for network in "$@"; do
    checkpoint=${network#*=}
    gate "$stage" "$checkpoint"  # a checkpoint whose training stage could not gate it (none of the recipe's)
    arguments+=(--checkpoint "$network")
  done
  if [ -n "${COMMIT:-}" ]; then  # the episodes so far every 5 looks: a session's end costs minutes, not the stage
    commit_progress "$stage" "its episodes so far" "$judged/$stage" "$judged/$stage/episodes.jsonl" $(( poll * 5 )) 0 \
      2> /dev/null &
    committer=$!
  fi
  step "stage $stage: benchmark v3 of $*"
  $bin/msfsu-benchmark "${arguments[@]}" --suite corl2017 nocrash --conditions train heldout --workers "$workers" \
    --out "$judged/$stage"
  stop_committer "$committer"
  v3_pages
  finish "$stage" "$judged/$stage" "$report"
}

run_stage() {
  case $1 in
    data-expert) data_stage data-expert collect_expert ;;
    data-dagger) data_stage data-dagger collect_dagger ;;
    train-msfsu | train-su | train-msf) train_stage "$1" "${1#train-}" "${1#train-}" ;;
    judge-msfsu) judge_stage judge-msfsu expert "msfsu_v3=$checkpoints/msfsu.pt" ;;
    judge-msf-su) judge_stage judge-msf-su no-expert "msf_v3=$checkpoints/msf.pt" "su_v3=$checkpoints/su.pt" ;;
    release)
      clock_start release
      $bin/msfsu-model-v3-release --baseline "$baseline:msfsu" --candidate "$judged/judge-msfsu:msfsu_v3" \
        --checkpoints "$checkpoints" --out "$record/release.json"
      finish release "$record/release.json" models
      ;;
    *) echo "model_v3.sh: no stage '$1' (stages: ${all_stages[*]})" >&2; exit 2 ;;
  esac
}

wanted=("$@")
[ ${#wanted[@]} -eq 0 ] && wanted=("${all_stages[@]}")
[ -z "${COMMIT:-}" ] || step "commits not yet submitted: after $(git rev-parse --short "$(submit_base)")" \
  "($(unsubmitted_mib) MiB of diffs; SUBMIT_BASE names another base)"
for stage in "${wanted[@]}"; do
  case $stage in data-*) ;; *) if done_already "$stage"; then step "stage $stage: done"; continue; fi ;; esac
  run_stage "$stage"
done
