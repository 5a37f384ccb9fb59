#!/usr/bin/env bash
# One-command setup from a fresh clone: venv, pinned dependencies, msfsu_interfaces, editable packages.
# Idempotent: each step is skipped when its inputs did not change since the last run.
# TORCH=cuda (make setup TORCH=cuda): the CUDA build of the pinned torch and ONNX Runtime's GPU build
# (onnxruntime-gpu), both from PyPI, with the CUDA libraries they need (several GB). The choice is kept in
# .venv/.torch: a later `make setup` keeps it; TORCH=cpu goes back to the CPU builds.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}

[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
# shellcheck disable=SC1091
source .venv/bin/activate

stamp_matches() { [ -f "$1" ] && [ "$(cat "$1")" = "$2" ]; }
torch_is_cuda_build() { python -c 'import sys, torch; sys.exit(torch.version.cuda is None)' 2>/dev/null; }

TORCH=${TORCH:-$(cat .venv/.torch 2>/dev/null || echo cpu)}
case "$TORCH" in
  cpu | cuda) ;;
  *) echo "setup: TORCH must be cpu or cuda, not '$TORCH'" >&2; exit 2 ;;
esac
torch_pin=$(grep -E '^torch==' requirements.txt)
onnxruntime_pin=$(grep -E '^onnxruntime==' requirements.txt)
# requirements.txt without ONNX Runtime's CPU build where its GPU build provides the same module
requirements=requirements.txt
if [ "$TORCH" = cuda ]; then
  requirements=.venv/requirements-cuda.txt
  grep -vE '^onnxruntime==' requirements.txt > "$requirements"
fi

requirements_hash=$(cat requirements.txt <(echo "$TORCH") | sha256sum | cut -d' ' -f1)
if ! stamp_matches .venv/.requirements.sha256 "$requirements_hash"; then
  echo "==> installing pinned dependencies (torch: $TORCH)"
  python -m pip install --quiet --upgrade pip
  if [ "$TORCH" = cuda ] && ! torch_is_cuda_build; then
    echo "==> the CUDA build of $torch_pin and onnxruntime-gpu${onnxruntime_pin#onnxruntime} from PyPI (several GB)"
    # PyPI's Linux wheels of torch are its CUDA builds; no pip configuration (so no local CPU wheel) is consulted.
    # Everything is fetched before anything is replaced: a failed download leaves the venv as it was.
    wheels=$(mktemp -d)
    if ! log=$(PIP_CONFIG_FILE=/dev/null python -m pip download --quiet --dest "$wheels" \
                 --index-url https://pypi.org/simple "$torch_pin" "onnxruntime-gpu${onnxruntime_pin#onnxruntime}" 2>&1); then
      rm -rf "$wheels"
      echo "setup: TORCH=cuda: the GPU builds ($torch_pin, onnxruntime-gpu${onnxruntime_pin#onnxruntime}) could not be fetched from PyPI ($(echo "$log" | grep -m1 -E 'ERROR|error' || echo "$log" | tail -n1)); the CPU build stays" >&2
      exit 1
    fi
    python -m pip uninstall --quiet -y onnxruntime torch
    PIP_CONFIG_FILE=/dev/null python -m pip install --quiet --no-index --find-links "$wheels" \
      "$torch_pin" "onnxruntime-gpu${onnxruntime_pin#onnxruntime}"
    rm -rf "$wheels"
  elif [ "$TORCH" = cpu ] && torch_is_cuda_build; then
    echo "==> back to the CPU builds of torch and ONNX Runtime"
    python -m pip uninstall --quiet -y torch onnxruntime-gpu
  fi
  python -m pip install --quiet -r "$requirements"
  echo "$TORCH" > .venv/.torch
  echo "$requirements_hash" > .venv/.requirements.sha256
fi

# OpenVINO/NNCF telemetry stays off (nothing may leave the machine); `opt_in_out --opt_out` would send an event.
mkdir -p "$HOME/intel" && echo 0 > "$HOME/intel/openvino_telemetry"

echo "==> message packages (msfsu_interfaces, carla_msgs)"
python scripts/build_interfaces.py

# Every ament_python package of the repository (msfsu_*/setup.py), installed editable.
mapfile -t PACKAGES < <(find . -maxdepth 2 -path './msfsu_*/setup.py' -printf '%h\n' | sed 's|^\./||' | sort)
packages_hash=$(cat "${PACKAGES[@]/%//setup.py}" "${PACKAGES[@]/%//setup.cfg}" | sha256sum | cut -d' ' -f1)
if ! stamp_matches .venv/.packages.sha256 "$packages_hash"; then
  echo "==> installing ${PACKAGES[*]} (editable)"
  editables=()
  for package in "${PACKAGES[@]}"; do editables+=(-e "./$package"); done
  PYTHONWARNINGS=ignore python -m pip install --quiet --no-deps --no-build-isolation \
    --config-settings editable_mode=compat "${editables[@]}"
  echo "$packages_hash" > .venv/.packages.sha256
fi
# Embedded simulator: headless EGL (Mesa llvmpipe) and MetaDrive's 3D assets, built offline (idempotent).
if ! dpkg -s libegl1 libegl-mesa0 libgl1-mesa-dri >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then
    echo "==> installing Mesa EGL (apt)"
    apt-get install -y --no-install-recommends libegl1 libegl-mesa0 libgl1-mesa-dri >/dev/null
  else
    echo "WARNING: the simulator needs Debian's libegl1 libegl-mesa0 libgl1-mesa-dri: sudo apt-get install them" >&2
  fi
fi
# tini, the Docker image's first process: tests/test_docker_image.py stops a stand-in container through it
if ! dpkg -s tini >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then
    echo "==> installing tini (apt)"
    apt-get install -y --no-install-recommends tini >/dev/null
  else
    echo "WARNING: the docker stop tests need Debian's tini (they skip without it): sudo apt-get install tini" >&2
  fi
fi
python -m msfsu_sim.assets
if [ "$TORCH" = cuda ]; then
  python -c 'import torch; print("==> torch", torch.__version__, "CUDA", torch.version.cuda, "device:",
                                torch.cuda.get_device_name() if torch.cuda.is_available() else "none found")'
fi
echo "==> setup complete: source .venv/bin/activate"
