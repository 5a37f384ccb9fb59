#!/usr/bin/env python3
"""Exit 1, saying why, unless the torch this Python imports is a CPU build and no nvidia-* (CUDA) distribution is
installed: the image's last word on docker/install_requirements.sh, whatever pulled a package in. Standard library
only (it reads the installed distributions' metadata, it imports no torch)."""

from __future__ import annotations

import importlib.metadata
import re
import sys


def main() -> int:
    try:
        version = importlib.metadata.version("torch")
    except importlib.metadata.PackageNotFoundError:
        print("check_torch_cpu.py: torch is not installed", file=sys.stderr)
        return 1
    names = {re.sub(r"[-_.]+", "-", distribution.metadata["Name"] or "").lower()  # PEP 503 normalised
             for distribution in importlib.metadata.distributions()}
    cuda = sorted(name for name in names if name.startswith("nvidia-"))
    if not version.endswith("+cpu") or cuda:
        print(f"check_torch_cpu.py: torch {version} with {cuda or 'no nvidia-* package'}: not PyTorch's CPU build",
              file=sys.stderr)
        return 1
    print(f"torch {version}, no nvidia-* package")
    return 0


if __name__ == "__main__":
    sys.exit(main())
