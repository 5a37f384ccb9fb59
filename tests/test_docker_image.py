"""What the Docker image (`ros:jazzy-ros-base`: Ubuntu 24.04, CPython 3.12, apt ROS) and an apt-ROS + colcon
install get, checked without building the image (docs/deployment_docker.md):

- docker/requirements.txt resolves for CPython 3.12 on manylinux x86_64 from PyPI alone (pip's dry run: no local
  index, configuration or constraint of this machine), with a setuptools that colcon-core accepts;
- a non-editable install of each package (what colcon builds) holds every data file of its modules;
- the replay graph, what the image is for, imports without the simulator (which the image does not have).
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from packaging.requirements import Requirement
from packaging.version import Version

REPO = Path(__file__).resolve().parents[1]
IMAGE_REQUIREMENTS = REPO / "docker" / "requirements.txt"
IMAGE_PYTHON = "3.12"  # Ubuntu 24.04's python3
IMAGE_GLIBC_MINOR = 39  # Ubuntu 24.04's glibc 2.39
PYTHON_PACKAGES = sorted(p.parent.name for p in REPO.glob("msfsu_*/setup.py"))
SIMULATOR_MODULES = ("metadrive", "panda3d", "direct", "meshoptimizer")  # not in the image
# PIP_* variables that only say how to reach the registry (trust, proxy, timeouts); every other one is dropped
PIP_TRANSPORT_VARIABLES = ("PIP_CERT", "PIP_CLIENT_CERT", "PIP_PROXY", "PIP_TRUSTED_HOST", "PIP_DEFAULT_TIMEOUT")
UNREACHABLE = ("NewConnectionError", "ConnectTimeoutError", "ReadTimeoutError", "ProxyError", "SSLError",
               "Could not fetch URL", "Temporary failure in name resolution", "Network is unreachable")


def pip_environment() -> dict[str, str]:
    """This environment with pip on its defaults: no configuration file, no index, link, constraint or other PIP_*
    setting of this machine (its CA bundle and proxy kept)."""
    env = {name: value for name, value in os.environ.items()
           if not name.startswith("PIP_") or name in PIP_TRANSPORT_VARIABLES}
    return dict(env, PIP_CONFIG_FILE=os.devnull, PIP_DISABLE_PIP_VERSION_CHECK="1")


def image_platforms() -> list[str]:
    """pip --platform tags of the wheels that install on the image: manylinux_2_39 down to 2_5 (pip widens
    manylinux2014 to its older aliases itself)."""
    return [f"manylinux_2_{minor}_x86_64" for minor in range(IMAGE_GLIBC_MINOR, 4, -1)] + ["manylinux2014_x86_64"]


def resolve_for_the_image(requirements: Path, report: Path) -> subprocess.CompletedProcess:
    platforms = [argument for platform in image_platforms() for argument in ("--platform", platform)]
    return subprocess.run(
        [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--report", str(report),
         "--python-version", IMAGE_PYTHON, "--implementation", "cp", "--abi", f"cp{IMAGE_PYTHON.replace('.', '')}",
         *platforms, "--only-binary=:all:", "--retries", "1", "--timeout", "30", "-r", str(requirements)],
        env=pip_environment(), capture_output=True, text=True, timeout=600)


def test_the_image_requirements_resolve_for_cpython_3_12_with_a_setuptools_colcon_accepts(tmp_path):
    result = resolve_for_the_image(IMAGE_REQUIREMENTS, tmp_path / "report.json")
    output = result.stdout + result.stderr
    if result.returncode != 0:
        unreachable = next((line.strip() for line in output.splitlines() if any(m in line for m in UNREACHABLE)), None)
        if unreachable:
            pytest.skip(f"PyPI cannot be reached from here: {unreachable}")
    assert result.returncode == 0, "\n".join(line for line in output.splitlines() if "ERROR" in line) or output[-3000:]
    resolved = {item["metadata"]["name"].lower(): Version(item["metadata"]["version"])
                for item in json.loads((tmp_path / "report.json").read_text())["install"]}
    colcon_setuptools = next(r for r in map(Requirement, importlib.metadata.requires("colcon-core"))
                             if r.name == "setuptools")
    assert resolved["setuptools"] in colcon_setuptools.specifier, (resolved["setuptools"], str(colcon_setuptools))


def package_data_files(package: str) -> list[Path]:
    """Every file in the package's module tree that is not Python: data its modules read, relative to the tree."""
    tree = REPO / package / package
    return sorted(p.relative_to(tree) for p in tree.rglob("*")
                  if p.is_file() and p.suffix not in (".py", ".pyc") and "__pycache__" not in p.parts)


@pytest.mark.parametrize("package", PYTHON_PACKAGES)
def test_a_non_editable_install_holds_every_data_file_of_the_package(package, tmp_path):
    source, target = tmp_path / "source", tmp_path / "target"
    shutil.copytree(REPO / package, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    result = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index", "--quiet",
         "--target", str(target), str(source)],
        env=pip_environment(), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    missing = [str(path) for path in package_data_files(package) if not (target / package / path).is_file()]
    assert not missing, f"{package}/setup.py does not install {missing} (package_data)"


def test_the_replay_graph_imports_without_the_simulator():
    """Every executable the replay profile starts, the launcher and msfsu-eval-bag import with the simulator's
    modules unavailable."""
    profile = yaml.safe_load((REPO / "msfsu_bringup" / "msfsu_bringup" / "profiles" / "replay.yaml").read_text())
    scripts = {entry.name: entry.module for entry in importlib.metadata.entry_points(group="console_scripts")}
    modules = [scripts[node["executable"]] for node in profile["nodes"]]
    modules += [scripts["msfsu-bringup"], scripts["msfsu-eval-bag"]]
    code = (f"import importlib, sys\nsys.modules.update(dict.fromkeys({SIMULATOR_MODULES!r}))\n"
            f"for module in {modules!r}:\n    importlib.import_module(module)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
