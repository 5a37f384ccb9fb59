#!/usr/bin/env bash
# docker/install_requirements.sh REQUIREMENTS [PIP OPTION ...]: one pip resolution of REQUIREMENTS into the system
# Python, torch as the CPU build only. torch's pin (`torch==V` in REQUIREMENTS) becomes the constraint `torch==V+cpu`,
# which only PyTorch's CPU index serves: where it lacks that build for this Python, the resolution fails, instead of
# taking PyPI's torch==V (the CUDA build, gigabytes of nvidia-* wheels). Everything else comes from PyPI.
# TORCH_INDEX_URL and PYPI_INDEX_URL name other indexes (a mirror; the tests: local ones).
set -euo pipefail
requirements=$1
shift
torch_index=${TORCH_INDEX_URL:-https://download.pytorch.org/whl/cpu}
pypi=${PYPI_INDEX_URL:-https://pypi.org/simple}
pin=$(grep -E '^torch==[^+[:space:]#]+' "$requirements" | head -n 1 | cut -d' ' -f1) || true
if [ -z "$pin" ]; then
    echo "install_requirements.sh: $requirements pins no torch==VERSION (the CPU build is pinned from it)" >&2
    exit 1
fi
constraints=$(mktemp)
trap 'rm -f "$constraints"' EXIT
echo "${pin}+cpu" > "$constraints"
# --ignore-installed: pip cannot uninstall apt's Python packages (no RECORD file), should a pin need another version
if ! pip3 install --ignore-installed --index-url "$torch_index" --extra-index-url "$pypi" \
        --constraint "$constraints" -r "$requirements" "$@"; then
    echo "install_requirements.sh: the resolution failed; if pip says torch has no matching distribution, $torch_index" \
         "has no ${pin#torch==}+cpu build for this Python: pin a torch version it has (never PyPI's, the CUDA build)" >&2
    exit 1
fi
