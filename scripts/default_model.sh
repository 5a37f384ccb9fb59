#!/usr/bin/env bash
# The recipe behind the shipped models/ and bags/sample (issue #12), with the project's own commands only.
# Every step resumes: collection skips finished bags, training continues from last.pt, finished steps are
# skipped. Frame caches (data/cache: one per variant's inputs and bag set) that the disk cannot hold beside a new one
# are deleted, least recently used first, and rebuilt if needed again. On 2 CPU cores: data ~1.5 h, each variant ~2 h of training.
#   1. expert data (round 0, steering-noise injection on): training towns x weathers x traffic levels, TRAIN_EPISODES
#      routes each; validation on the training towns and weathers (clean labels); the held-out gate bags
#   2. round 0: MSFSU, MSF and SU, ROUND0_EPOCHS epochs each on the expert data
#   3. DAgger (Ross et al. 2011), rounds 1..ROUNDS: MSFSU of the round before drives (beta = 0.5^round), the expert
#      labels every frame; each variant continues on the aggregate up to ROUND0_EPOCHS + round * ROUND_EPOCHS
#      epochs: one data set and one budget for the three (the ablation is fair)
#   VARIANTS=msfsu runs MSFSU alone (the default model first); MSF and SU need $RUNS/msfsu/round*.pt (their drivers)
#   FOCUS_COPIES=N: each DAgger round's training repeats the on-policy focus frames N more times (where the network
#      crashed or nearly did: msfsu_perception.bag_index.FocusConfig); 0 (default): plain DAgger
#   BRANCH=1: for MSFSU, also the same-budget branch without round N's data: from round N-1's last epoch, the same
#      epochs on rounds 0..N-1 only (RUNS/msfsu_branch<N>/: round<N>.pt its best, last.pt its last epoch); its last
#      epoch is what round N's last epoch (RUNS/msfsu/round<N>.last.pt) is measured against (scripts/results.sh)
#   4. fp16 releases into models/ (at most 30 MB each), a held-out sample bag into bags/sample, the data's report into
#      DATA_REPORT (default docs/results/data)
# The closed-loop comparison of the rounds (training routes only) and of the variants: scripts/results.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
data=${DATA:-data/v2}
runs=${RUNS:-runs/v2}
workers=${WORKERS:-2}
train_episodes=${TRAIN_EPISODES:-3}
round0_epochs=${ROUND0_EPOCHS:-5}
round_epochs=${ROUND_EPOCHS:-5}
rounds=${ROUNDS:-1}
variants=(${VARIANTS:-msfsu msf su})
focus_copies=${FOCUS_COPIES:-0}
branch=${BRANCH:-}
bin=.venv/bin
# one timestamped line per step into the log (a run of many sessions reads as a timeline: grep '^\[msfsu ')
step() { echo "[msfsu $(date -u +%Y-%m-%dT%H:%M:%SZ)] $*"; }
# A copy that a stop cannot leave half-written (a session's end kills whatever runs): the steps below are skipped
# when their output exists, so each step's outputs are copied this way, the one its skip test reads last.
publish() { cp "$1" "$2.partial" && mv -f "$2.partial" "$2"; }

# 1. data
step "expert data into $data (train, validation, gate bags)"
$bin/msfsu-collect --output "$data" --split train --episodes "$train_episodes" --max-steps 900 --workers "$workers"
$bin/msfsu-collect --output "$data" --split validation --episodes 1 --traffic regular dense --max-steps 400 \
  --no-noise --workers "$workers"
GATE_DATA="$data/gate" WORKERS="$workers" bash scripts/gate_bags.sh

# Training bags of rounds 0..$1: round 0 is named <town>_<weather>_<traffic>_<index>, round N adds _rN.
train_bags() {
  local patterns=("$data/train/*_[0-9][0-9][0-9]")
  for ((r = 1; r <= $1; r++)); do patterns+=("$data/train/*_r$r"); done
  echo "${patterns[@]}"
}

# $1 variant, $2 last round of data, $3 epochs in all (continues the run's last.pt), $4 run name (default: $1)
train() {
  local name=${4:-$1} resume=()
  [ -e "$runs/$name/last.pt" ] && resume=(--resume)
  step "train $name: variant $1 on rounds 0..$2, up to $3 epochs${resume:+ (resumed)}"
  # shellcheck disable=SC2046
  $bin/msfsu-train --train-bags $(train_bags "$2") --val-bags "$data/validation/*" --preset cpu \
    --variant "$1" --epochs "$3" --num-threads 2 --focus-copies "$focus_copies" --out "$runs/$name" --evict-caches \
    "${resume[@]}"
  # the run's record (one metrics.csv row per epoch: losses, lr, samples/s, epoch time) is committed
  mkdir -p "docs/results/training/$name"
  cp "$runs/$name/metrics.csv" "$runs/$name/loss_curves.png" "$runs/$name/balancing.png" "docs/results/training/$name/"
}

# 2.-3. per variant, MSFSU first (its round-N model drives round N + 1): round 0 on the expert data, then each
#    DAgger round's data collected (once) and the run continued on the aggregate. roundN.pt keeps each round's best.
for variant in "${variants[@]}"; do
  if [ ! -e "$runs/$variant/round0.pt" ]; then
    train "$variant" 0 "$round0_epochs"
    publish "$runs/$variant/last.pt" "$runs/$variant/round0.last.pt"  # to branch from: the same epochs without DAgger
    publish "$runs/$variant/best.pt" "$runs/$variant/round0.pt"
  fi
  for ((round = 1; round <= rounds; round++)); do
    [ -e "$runs/$variant/round$round.pt" ] && continue
    step "DAgger round $round data: $runs/msfsu/round$((round - 1)).pt drives, the expert labels"
    $bin/msfsu-collect --output "$data" --split train --episodes 1 --max-steps 900 --workers "$workers" \
      --driver "$runs/msfsu/round$((round - 1)).pt" --beta "$($bin/python -c "print(0.5 ** $round)")" --round "$round"
    fork="msfsu_branch$round"
    if [ -n "$branch" ] && [ "$variant" = msfsu ] && [ ! -e "$runs/$fork/round$round.pt" ]; then
      # from round N-1's last epoch, the same epochs on the data of rounds 0..N-1 only: the same budget without the
      # round's on-policy data, what the DAgger round is measured against (its best.pt starts as round N-1's best)
      if [ ! -e "$runs/$fork/last.pt" ]; then
        mkdir -p "$runs/$fork"
        publish "$runs/msfsu/round$((round - 1)).pt" "$runs/$fork/best.pt"
        publish "$runs/msfsu/round$((round - 1)).last.pt" "$runs/$fork/last.pt"
      fi
      train msfsu $((round - 1)) $((round0_epochs + round * round_epochs)) "$fork"
      publish "$runs/$fork/best.pt" "$runs/$fork/round$round.pt"
    fi
    train "$variant" "$round" $((round0_epochs + round * round_epochs))
    publish "$runs/$variant/last.pt" "$runs/$variant/round$round.last.pt"
    publish "$runs/$variant/best.pt" "$runs/$variant/round$round.pt"
  done
done

# 4. releases and the sample bag
step "releases into models/ and the sample bag"
declare -A released=([msfsu]=msfsu_default [msf]=msf [su]=su)
for variant in "${variants[@]}"; do
  $bin/msfsu-release-checkpoint "$runs/$variant/round$rounds.pt" "models/${released[$variant]}.pt"
done
# A held-out town and weather the networks never saw, regular traffic: base seed 2030 draws a 185 m route that turns
# LEFT, then RIGHT. The bag keeps steps 126-224 (99 frames, 9.9 s, 24.8 MB of the 25 MB allowed): the left turn from its
# start, cars in view, the RIGHT command of the next junction.
$bin/msfsu-collect --output "$data/sample" --split test --towns town_h1 --weathers soft_rain_dusk \
  --traffic regular --record-from 126 --max-steps "${SAMPLE_MAX_STEPS:-225}" --seed "${SAMPLE_SEED:-2030}" --no-noise --workers 1
sample="$data/sample/test/town_h1_soft_rain_dusk_regular_000"
sample_bytes=$(du -sb "$sample" | cut -f1)
if (( sample_bytes > 25000000 )); then  # a committed bag weighs at most 25 MB (10^6 bytes)
  echo "default_model.sh: the sample bag $sample is $sample_bytes bytes, over 25 MB: delete" \
    "$data/sample and re-run with fewer frames (SAMPLE_MAX_STEPS below 225)" >&2
  exit 1
fi
rm -rf bags/sample && cp -r "$sample" bags/sample
$bin/msfsu-dataset-report "$data" --out "${DATA_REPORT:-docs/results/data}"
du -sh models/*.pt bags/sample
step "done"
