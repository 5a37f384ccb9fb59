#!/usr/bin/env bash
# One-command setup from a fresh clone: venv, pinned dependencies, msfsu_interfaces, editable packages.
# Idempotent: each step is skipped when its inputs did not change since the last run.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}

[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
# shellcheck disable=SC1091
source .venv/bin/activate

stamp_matches() { [ -f "$1" ] && [ "$(cat "$1")" = "$2" ]; }

requirements_hash=$(sha256sum requirements.txt | cut -d' ' -f1)
if ! stamp_matches .venv/.requirements.sha256 "$requirements_hash"; then
  echo "==> installing pinned dependencies"
  python -m pip install --quiet --upgrade pip
  python -m pip install --quiet -r requirements.txt
  echo "$requirements_hash" > .venv/.requirements.sha256
fi

# OpenVINO/NNCF telemetry stays off (nothing may leave the machine); `opt_in_out --opt_out` would send an event.
mkdir -p "$HOME/intel" && echo 0 > "$HOME/intel/openvino_telemetry"

echo "==> msfsu_interfaces"
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
python -m msfsu_sim.assets
echo "==> setup complete: source .venv/bin/activate"
