"""Build the message packages (.msg -> Python/C type support) into the virtual environment: msfsu_interfaces
and carla_msgs (carla-ros-bridge's messages, neither a pip wheel nor a Jazzy apt package; carla_msgs/package.xml).

    python scripts/build_interfaces.py [PACKAGE ...]     # default: every one of PACKAGES

The pip ROS 2 wheels carry CMake config files that point at the wheel build machine's Python and
numpy include directories; they are rewritten to this interpreter's paths (idempotent) before a
plain CMake build installs each package into the venv prefix, where the bootstrapper finds it with
no sourcing. A content hash of each package makes re-runs instant when nothing changed.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("msfsu_interfaces", "carla_msgs")  # ament_cmake message packages at the repository's root
WHEEL_PYTHON_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
WHEEL_NUMPY_INCLUDE = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


def package_hash(package: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*")):
        if path.is_file():
            digest.update(path.relative_to(package).as_posix().encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def patch_wheel_cmake_files(prefix: Path) -> int:
    """Point the wheels' CMake files at this interpreter's include directories; returns files changed."""
    replacements = {
        WHEEL_PYTHON_INCLUDE: sysconfig.get_paths()["include"],
        WHEEL_NUMPY_INCLUDE: numpy.get_include(),
    }
    changed = 0
    for cmake_file in (prefix / "share").glob("*/cmake/*.cmake"):
        text = cmake_file.read_text()
        patched = text
        for old, new in replacements.items():
            patched = patched.replace(old, new)
        if patched != text:
            cmake_file.write_text(patched)
            changed += 1
    return changed


def build(name: str, prefix: Path) -> int:
    """Build and install message package `name` into `prefix` unless its installed hash is this source's."""
    package = REPO / name
    stamp = prefix / "share" / name / "build.sha256"
    wanted = package_hash(package)
    if stamp.is_file() and stamp.read_text() == wanted:
        print(f"{name}: up to date")
        return 0
    patched = patch_wheel_cmake_files(prefix)
    print(f"{name}: patched {patched} wheel CMake files")
    build_dir = REPO / "build" / name
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix), CMAKE_PREFIX_PATH=str(prefix))
    commands = [
        ["cmake", "-S", str(package), "-B", str(build_dir), "-G", "Ninja",
         f"-DCMAKE_INSTALL_PREFIX={prefix}", "-DBUILD_TESTING=OFF",
         f"-DPython3_EXECUTABLE={sys.executable}", "-DCMAKE_BUILD_TYPE=Release"],
        ["cmake", "--build", str(build_dir)],
        ["cmake", "--install", str(build_dir)],
    ]
    for command in commands:
        result = subprocess.run(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        if result.returncode != 0:
            print(result.stdout[-6000:], file=sys.stderr)
            print(f"{name}: '{' '.join(command[:3])}' failed", file=sys.stderr)
            return result.returncode
    stamp.write_text(wanted)
    print(f"{name}: built and installed into {prefix}")
    return 0


def main(names: list[str]) -> int:
    unknown = sorted(set(names) - set(PACKAGES))
    if unknown:
        print(f"build_interfaces: no message package {', '.join(unknown)} (packages: {', '.join(PACKAGES)})",
              file=sys.stderr)
        return 2
    prefix = Path(sys.prefix)
    for name in names or PACKAGES:
        code = build(name, prefix)
        if code:
            return code
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
