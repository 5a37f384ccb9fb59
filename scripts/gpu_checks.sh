#!/usr/bin/env bash
# The GPU checks (issue 26), on a machine with a CUDA device, in one go:
#   1. the tests marked gpu (the network in a CUDA graph against torch fp32 on the CPU, preprocessing on the GPU);
#   2. benchmarks/gpu.py --record-gate: latency per path and stage, the gate of the GPU precisions, their verdicts
#      stored beside models/msfsu_default.pt (which precision "auto" then takes on a GPU);
#   3. benchmarks/training.py on the GPU: the paper preset with the paper's batch 32, then with its GPU default.
# Results go beside the benchmarks, or into OUT_DIR (then copy them back). Each step runs even if one before it failed;
# the exit status says whether all passed. PYTHON: the interpreter (default .venv/bin/python). PAPER_BATCH_STEPS,
# GPU_BATCH_STEPS: N of the two training benchmarks (default 40 and 20; each trains N and 2N steps, the difference is
# its steady state).
set -uo pipefail
cd "$(dirname "$0")/.."
py=${PYTHON:-.venv/bin/python}
out=${OUT_DIR:-benchmarks}
status=0
echo "==> gpu tests"
"$py" -m pytest -q -p no:cacheprovider --noconftest -o addopts="-ra --strict-markers" -m gpu \
  msfsu_perception/test/test_gpu_runner.py msfsu_perception/test/test_device_preprocessing.py \
  msfsu_perception/test/test_train.py || status=1
echo "==> benchmarks/gpu.py"
"$py" benchmarks/gpu.py --record-gate --out "$out/gpu_results.md" || status=1
if [ "$out" != benchmarks ] && [ -f benchmarks/training_results.json ]; then
  cp benchmarks/training_results.json "$out/training_results.json"  # the CPU rows stay in the table
fi
echo "==> benchmarks/training.py (paper preset, the paper's batch)"
"$py" benchmarks/training.py --preset paper --device cuda --batch-size 32 --learning-rate 3e-4 --steps "${PAPER_BATCH_STEPS:-40}" \
  --out "$out/training_results.md" || status=1
echo "==> benchmarks/training.py (paper preset, its GPU defaults)"
"$py" benchmarks/training.py --preset paper --device cuda --steps "${GPU_BATCH_STEPS:-20}" --out "$out/training_results.md" || status=1
exit $status
