"""Every package.xml declares what its package's Python code uses, and nothing it does not use.

What counts as a use (Python files of the package, tests separately):
- a top-level import (`import x.y` / `from x.y import z`, anywhere in the file, lazy ones included);
- a message type named as a string (`"geometry_msgs/msg/Pose"`, resolved at run time by
  msfsu_common.message_types or a rosbags typestore): the package that defines it;
- for msfsu_bringup, the `package:` of every node its shipped profiles start.

Imports are sorted into the standard library (ignored), ROS packages (the workspace's msfsu_* and
every package in the ament index: must be a <depend>/<exec_depend>, for tests also a <test_depend>)
and the Python packages of THIRD_PARTY (their rosdep key must be declared, or, without a rosdep key,
the PyPI name must be named in a package.xml comment). An import in none of these fails the test:
classify it here.
"""

from __future__ import annotations

import ast
import os
import re
import runpy
import sys
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import setuptools
import yaml

REPO = Path(__file__).resolve().parents[1]
PYTHON_PACKAGES = sorted(p.parent.name for p in REPO.glob("msfsu_*/setup.py"))
WORKSPACE_PACKAGES = {p.parent.name for p in REPO.glob("msfsu_*/package.xml")}

# import name -> (PyPI distribution installed by requirements.txt, rosdep key or None = no key in rosdistro's
# rosdep/python.yaml). The -pip keys install from PyPI (python3-pytorch-pip: torch and torchvision).
THIRD_PARTY = {
    "numpy": ("numpy", "python3-numpy"),
    "cv2": ("opencv-python-headless", "python3-opencv"),
    "yaml": ("pyyaml", "python3-yaml"),
    "matplotlib": ("matplotlib", "python3-matplotlib"),
    "tqdm": ("tqdm", "python3-tqdm"),
    "pytest": ("pytest", "python3-pytest"),
    "torch": ("torch", "python3-pytorch-pip"),
    "rosbags": ("rosbags", "python3-rosbags-pip"),
    "onnx": ("onnx", None),
    "onnxruntime": ("onnxruntime", "python3-onnxruntime-pip"),
    "openvino": ("openvino", None),
    "nncf": ("nncf", None),
    "metadrive": ("metadrive-simulator", None),
    "panda3d": ("panda3d", None),  # installed with metadrive-simulator
    "direct": ("panda3d", None),  # panda3d's `direct` package
    "imageio_ffmpeg": ("imageio-ffmpeg", None),
    "mcap": ("mcap", None),
    "hypothesis": ("hypothesis", "python3-hypothesis"),
    "meshoptimizer": ("meshoptimizer", None),
    "doit": ("doit", None),  # the recipes' pipelines (msfsu_evaluation.pipelines), pip only here
    "psutil": ("psutil", "python3-psutil"),
}
PULLED_IN = {"panda3d"}  # distributions requirements.txt gets through another pin (metadrive-simulator)

# Declared dependencies that no import shows, and why they are needed.
NOT_IMPORTED = {
    ("msfsu_common", "msfsu_interfaces"): "bag_io reads its msg/*.msg files into the bag typestore",
}

# ROS packages of apt's ROS 2 that the pip wheels lack (no launch wheels): msfsu_bringup's launch files import them and
# declare them like every ROS package; they are ROS packages wherever the code runs, in an ament index or not
APT_ONLY_ROS_PACKAGES = {"launch", "launch_ros"}

MESSAGE_TYPE = re.compile(r"([a-z][a-z0-9_]*)/(?:msg|srv|action)/[A-Z][A-Za-z0-9]*")
RUN_DEPENDS = ("depend", "exec_depend")


@dataclass
class Uses:
    """Packages a set of files uses, each with the first place that shows it."""

    ros: dict[str, str] = field(default_factory=dict)
    python: dict[str, str] = field(default_factory=dict)
    unknown: dict[str, str] = field(default_factory=dict)


@pytest.fixture(scope="module")
def ament_packages() -> set[str]:
    """The ament index of the environment (the venv's pip ROS, or AMENT_PREFIX_PATH) + the workspace."""
    prefixes = [sys.prefix, *filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep))]
    index = [Path(prefix) / "share" / "ament_index" / "resource_index" / "packages" for prefix in prefixes]
    found = {entry.name for directory in index if directory.is_dir() for entry in directory.iterdir()}
    assert "rclpy" in found, f"no ament index with rclpy under {prefixes}"
    return found | WORKSPACE_PACKAGES | APT_ONLY_ROS_PACKAGES


def manifest(package: str) -> ElementTree.Element:
    return ElementTree.parse(REPO / package / "package.xml").getroot()


def declared(package: str, *tags: str) -> set[str]:
    root = manifest(package)
    return {element.text.strip() for tag in tags for element in root.findall(tag)}


def manifest_comments(package: str) -> str:
    return " ".join(re.findall(r"<!--(.*?)-->", (REPO / package / "package.xml").read_text(), re.DOTALL))


def file_uses(path: Path) -> list[tuple[str, str]]:
    """(kind, name) for every top-level import ("import") and message type package ("message")."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [("import", alias.name.split(".")[0]) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append(("import", node.module.split(".")[0]))
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            match = MESSAGE_TYPE.fullmatch(node.value)
            if match:
                found.append(("message", match.group(1)))
    return found


def uses(package: str, directory: Path, ament_packages: set[str]) -> Uses:
    result = Uses()
    for path in sorted(directory.rglob("*.py")):
        where = str(path.relative_to(REPO) if path.is_relative_to(REPO) else path)
        for kind, name in file_uses(path):
            if name == package or name in sys.stdlib_module_names:
                continue
            if kind == "message" or name in ament_packages:
                result.ros.setdefault(name, where)
            elif name in THIRD_PARTY:
                result.python.setdefault(name, where)
            else:
                result.unknown.setdefault(name, where)
    if directory.name == package:  # the package's own code: + the nodes its profiles start
        for profile in sorted(directory.glob("profiles/*.yaml")):
            for node in yaml.safe_load(profile.read_text())["nodes"]:
                if node["package"] != package:
                    result.ros.setdefault(node["package"], profile.name)
    return result


def requirement_names() -> set[str]:
    names = set()
    for line in (REPO / "requirements.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            names.add(re.split(r"[\[<>=!~ ]", line)[0].lower().replace("_", "-"))
    return names | PULLED_IN


def check(package: str, directory: Path, allowed: set[str], ament_packages: set[str]) -> list[str]:
    found, comments, problems = uses(package, directory, ament_packages), manifest_comments(package), []
    for name, where in found.unknown.items():
        problems.append(f"{where} imports {name}: not stdlib, not an ament package, not in THIRD_PARTY")
    for name, where in sorted(found.ros.items()):
        if name not in allowed:
            problems.append(f"{package}/package.xml does not declare {name} ({where} uses it)")
    for name, where in sorted(found.python.items()):
        distribution, rosdep_key = THIRD_PARTY[name]
        if rosdep_key is not None and rosdep_key not in allowed:
            problems.append(f"{package}/package.xml does not declare {rosdep_key} ({where} imports {name})")
        if rosdep_key is None and distribution not in comments:
            problems.append(f"{package}/package.xml: no comment names pip-only {distribution} ({where} imports {name})")
    return problems


@pytest.mark.parametrize("package", PYTHON_PACKAGES)
def test_package_xml_declares_what_the_package_uses(package, ament_packages):
    run = declared(package, *RUN_DEPENDS)
    problems = check(package, REPO / package / package, run, ament_packages)
    problems += check(package, REPO / package / "test", run | declared(package, "test_depend"), ament_packages)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("package", PYTHON_PACKAGES)
def test_package_xml_declares_nothing_the_package_does_not_use(package, ament_packages):
    source = uses(package, REPO / package / package, ament_packages)
    tests = uses(package, REPO / package / "test", ament_packages)
    python_keys = {THIRD_PARTY[name][1] for name in source.python}
    used = set(source.ros) | python_keys | {dep for (owner, dep) in NOT_IMPORTED if owner == package}
    unused = sorted(declared(package, *RUN_DEPENDS) - used)
    assert not unused, f"{package}/package.xml declares {unused}, which its code does not use (or add to NOT_IMPORTED)"
    test_used = used | set(tests.ros) | {THIRD_PARTY[name][1] for name in tests.python}
    unused_tests = sorted(declared(package, "test_depend") - test_used)
    assert not unused_tests, f"{package}/package.xml: test_depend {unused_tests} not used by its tests"


def test_pip_only_imports_are_installed_by_the_setup():
    names = requirement_names()
    assert {distribution for distribution, _ in THIRD_PARTY.values()} <= names


def test_the_check_finds_an_undeclared_ros_import(tmp_path, ament_packages):
    """The check itself: a package that imports a sibling and a message package it does not declare."""
    (tmp_path / "msfsu_common").mkdir()
    (tmp_path / "msfsu_common" / "x.py").write_text(
        "from msfsu_sim.route import Route\nimport geometry_msgs.msg\nT = 'nav_msgs/msg/Odometry'\nimport numpy\n"
        "import not_a_known_module\n")
    problems = check("msfsu_common", tmp_path / "msfsu_common", declared("msfsu_common", *RUN_DEPENDS), ament_packages)
    joined = "\n".join(problems)
    for name in ("msfsu_sim", "geometry_msgs", "nav_msgs", "not_a_known_module"):
        assert name in joined
    assert "numpy" not in joined  # python3-numpy is declared


@pytest.mark.parametrize("package", PYTHON_PACKAGES)
def test_setup_py_matches_package_xml_and_installs_existing_files(package, monkeypatch):
    captured = {}
    monkeypatch.setattr(setuptools, "setup", lambda **kwargs: captured.update(kwargs))
    monkeypatch.chdir(REPO / package)
    runpy.run_path("setup.py")
    root = manifest(package)
    assert captured["name"] == root.findtext("name") == package
    assert captured["version"] == root.findtext("version")
    assert captured["description"] == root.findtext("description")
    assert captured["license"] == root.findtext("license")
    for destination, files in captured["data_files"]:
        assert files, f"{package}/setup.py: data_files {destination} matches no file"
        assert all(Path(name).is_file() for name in files), files
    for module, patterns in captured.get("package_data", {}).items():
        for pattern in patterns:
            assert list(Path(*module.split(".")).glob(pattern)), f"{package}/setup.py: {module} {pattern} matches nothing"
