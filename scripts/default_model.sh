#!/usr/bin/env bash
# The recipe behind the shipped models/ and bags/sample (issue #6), with the project's own commands only.
# Resumable: collection skips finished bags, training resumes from last.pt. About 1 h 40 min on 2 CPU cores.
#   1. expert data (noise injection on): training towns x weathers x traffic levels; validation on the
#      training towns; test on the held-out towns and weathers (no noise: every frame is scored)
#   2. the cpu preset for MSFSU, MSF and SU with the same epoch budget
#   3. fp16 releases into models/, and a held-out sample bag into bags/sample
set -euo pipefail
cd "$(dirname "$0")/.."
data=${DATA:-data/sim}
runs=${RUNS:-runs/default_model}
epochs=${EPOCHS:-3}
workers=${WORKERS:-2}
bin=.venv/bin

$bin/msfsu-collect --output "$data" --split train --episodes 1 --traffic empty regular dense \
  --max-steps 300 --workers "$workers"
$bin/msfsu-collect --output "$data" --split validation --episodes 1 --weathers wet_cloudy \
  --traffic regular --max-steps 150 --workers "$workers"
$bin/msfsu-collect --output "$data" --split test --episodes 1 --traffic regular --max-steps 200 \
  --no-noise --workers "$workers"

for variant in msfsu msf su; do
  resume=()
  [ -e "$runs/$variant/last.pt" ] && resume=(--resume)
  $bin/msfsu-train --train-bags "$data/train/*" --val-bags "$data/validation/*" --preset cpu \
    --variant "$variant" --epochs "$epochs" --out "$runs/$variant" "${resume[@]}"
done
$bin/msfsu-release-checkpoint "$runs/msfsu/best.pt" models/msfsu_default.pt
$bin/msfsu-release-checkpoint "$runs/msf/best.pt" models/msf.pt
$bin/msfsu-release-checkpoint "$runs/su/best.pt" models/su.pt

# A held-out town and weather the networks never saw, 12 s of regular traffic (~20 MB with zstd chunks).
$bin/msfsu-collect --output "$data/sample" --split test --towns town_h1 --weathers soft_rain_dusk \
  --traffic regular --max-steps 120 --seed 2026 --no-noise --workers 1
rm -rf bags/sample && cp -r "$data/sample/test/town_h1_soft_rain_dusk_regular_000" bags/sample
du -sh models/*.pt bags/sample
