"""Sizes of the Docker image's own layers, measured without a Docker engine (with one, `docker history msfsu`).

    python benchmarks/image_layers.py     # writes benchmarks/image_layers_results.{md,json}

- the pip layer (`docker/install_requirements.sh`): the installed size of every distribution docker/requirements.txt
  resolves to, as the same pins are installed in this environment (`make setup`'s, CPython 3.11; the image's CPython
  3.12 wheels differ a little, and its numpy<2 and opencv-python-headless 4.10 differ from this environment's);
- `COPY . /opt/msfsu`: the build context, `.dockerignore` read as Docker reads it (tests/test_docker_image.py's
  reader, the one its context test checks);
- the int8 step (`msfsu_perception.prepare_model models/msfsu_default.pt --precision int8`): the derived files it
  writes, built here into a copy of the shipped default model.

Not measured here: the base image (`ros:jazzy-ros-base`, not pulled) and the apt layer.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import platform
import re
import shutil
import sys
import tempfile
from pathlib import Path

from packaging.requirements import Requirement

REPO = Path(__file__).resolve().parents[1]
OUT = Path(__file__).with_name("image_layers_results.md")
SHIPPED = REPO / "models" / "msfsu_default.pt"


def distribution_closure(requirements: Path) -> dict[str, importlib.metadata.Distribution]:
    """Every installed distribution the requirements file names or needs (markers evaluated, no extras)."""
    found: dict[str, importlib.metadata.Distribution] = {}
    pending = [line.split("#")[0].strip() for line in requirements.read_text().splitlines()]
    pending = [line for line in pending if line]
    while pending:
        requirement = Requirement(pending.pop())
        if requirement.marker is not None and not requirement.marker.evaluate({"extra": ""}):
            continue
        key = re.sub(r"[-_.]+", "-", requirement.name).lower()
        if key in found:
            continue
        try:
            distribution = importlib.metadata.distribution(requirement.name)
        except importlib.metadata.PackageNotFoundError:
            continue
        found[key] = distribution
        pending += distribution.requires or []
    return found


def installed_bytes(distribution: importlib.metadata.Distribution) -> int:
    total = 0
    for file in distribution.files or []:
        path = Path(distribution.locate_file(file))
        if path.is_file():
            total += path.stat().st_size
    return total


def context_bytes() -> int:
    spec = importlib.util.spec_from_file_location("test_docker_image", REPO / "tests" / "test_docker_image.py")
    sys.path.insert(0, str(REPO / "tests"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return sum(module.build_context(module.ignore_patterns()).values())


def int8_step_files() -> dict[str, int]:
    """name (its kind) -> bytes of what prepare_model writes for a copy of the shipped default model."""
    from msfsu_perception.deploy_files import DeployFiles, calibration_path
    from msfsu_perception.prepare_model import main as prepare

    with tempfile.TemporaryDirectory() as directory:
        checkpoint = Path(directory) / SHIPPED.name
        shutil.copy(SHIPPED, checkpoint)
        shutil.copy(calibration_path(SHIPPED), calibration_path(checkpoint))
        store = DeployFiles(checkpoint)
        store.directory.mkdir()
        shutil.copy(DeployFiles(SHIPPED).int8_recipe, store.int8_recipe)  # in the build context already
        if prepare([str(checkpoint), "--precision", "int8"]) != 0:
            raise SystemExit("image_layers: the int8 step failed")
        sizes: dict[str, int] = {}
        for path in store.directory.rglob("*"):
            if path.is_file() and path != store.int8_recipe:
                kind = path.relative_to(store.directory).parts[0].removeprefix(store.prefix + "-")
                kind = re.sub(r"^int8-[0-9a-f]+-[0-9a-f]+", "int8", kind)
                sizes[kind] = sizes.get(kind, 0) + path.stat().st_size
        return sizes


def megabytes(count: int) -> str:
    if count < 1e6:
        return f"{count / 1e3:.0f} kB"
    return f"{count / 1e6:.0f} MB" if count < 1e9 else f"{count / 1e9:.1f} GB"


def main() -> int:
    closure = distribution_closure(REPO / "docker" / "requirements.txt")
    pip = sorted(((installed_bytes(d), d.metadata["Name"], d.version) for d in closure.values()), reverse=True)
    pip_total = sum(size for size, _, _ in pip)
    context = context_bytes()
    derived = int8_step_files()
    record = {"python": platform.python_version(), "machine": platform.machine(),
              "pip": {"bytes": pip_total, "distributions": [{"name": n, "version": v, "bytes": s} for s, n, v in pip]},
              "context_bytes": context, "int8_step": derived}
    OUT.with_suffix(".json").write_text(json.dumps(record, indent=2) + "\n")
    largest = ", ".join(f"{name} {megabytes(size)}" for size, name, _ in pip[:5])
    lines = ["# The Docker image's own layers", "",
             "`python benchmarks/image_layers.py` (no Docker engine: the module doc says how each is measured; with "
             "one, `docker history msfsu`).", "",
             "| layer | size |", "| --- | --- |",
             f"| `docker/install_requirements.sh` (pip; the same pins in this environment, CPython "
             f"{platform.python_version()}: {largest}, ...) | {megabytes(pip_total)} ({len(pip)} distributions) |",
             f"| `COPY . /opt/msfsu` (the build context) | {megabytes(context)} |",
             f"| `prepare_model` (the int8 step: {', '.join(f'{k} {megabytes(v)}' for k, v in sorted(derived.items()))}"
             f") | {megabytes(sum(derived.values()))} |",
             "| base `ros:jazzy-ros-base`, apt (`python3-pip`, `ros-jazzy-rosbag2-storage-mcap`, `tini`) | not "
             "measured here |", ""]
    OUT.write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
