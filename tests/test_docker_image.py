"""What the Docker image (`ros:jazzy-ros-base`: Ubuntu 24.04, CPython 3.12, apt ROS) and an apt-ROS + colcon
install get, checked without building the image (docs/deployment_docker.md):

- docker/requirements.txt resolves for CPython 3.12 on manylinux x86_64 from PyPI alone (pip's dry run: no local
  index, configuration or constraint of this machine), with a setuptools that colcon-core accepts;
- a non-editable install of each package (what colcon builds) holds every data file of its modules;
- the replay graph, what the image is for, imports without the simulator (which the image does not have);
- the Dockerfile: the base pinned by digest, pip's settings left out of the image's environment; apt's tini as the
  first process with the process-group option, SIGINT as the stop signal; the default model's int8 network built
  during the build by the node's own loading code; a default command that starts the graph on the shipped sample;
  the build context (.dockerignore) is what the image needs; torch comes from the CPU index as its +cpu build or the
  build fails, and a last check refuses any CUDA package;
- `docker stop`: the ENTRYPOINT (tini and the entry point), run as the container's first process would be, passes
  the stop signal on to every node, under `ros2 run` or the launcher, and ends only once they have shut down.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
import yaml
from packaging.requirements import Requirement
from packaging.version import Version
from process_hygiene import alive, descendants
from ros2cli import ros2cli_environment

from msfsu_bringup.bag_player import STARTED_MESSAGE
from msfsu_common import topics
from msfsu_common.bag_io import METADATA_FILE
from msfsu_perception.synthetic import write_synthetic_bag

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


# --- the Dockerfile ------------------------------------------------------------------------------------------------
DOCKERFILE = REPO / "Dockerfile"


def dockerfile_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of the Dockerfile, continuation lines joined, comments left out."""
    text = re.sub(r"\\\n", " ", "\n".join(line for line in DOCKERFILE.read_text().splitlines()
                                          if not line.lstrip().startswith("#")))
    return [(line.split(None, 1)[0].upper(), line.split(None, 1)[1]) for line in text.splitlines() if line.strip()]


def instruction(name: str) -> str:
    [arguments] = [arguments for found, arguments in dockerfile_instructions() if found == name]
    return arguments


def test_tini_from_apt_is_the_first_process_and_docker_stop_sends_the_ros_stop_signal():
    entrypoint = json.loads(instruction("ENTRYPOINT"))
    assert entrypoint[0] == "/usr/bin/tini" and {"-g", "-s"} <= set(entrypoint[1:entrypoint.index("--")])
    assert entrypoint[entrypoint.index("--") + 1:] == ["/opt/msfsu/docker/entrypoint.sh"]
    apt = [arguments for found, arguments in dockerfile_instructions()
           if found == "RUN" and "apt-get install" in arguments]
    assert len(apt) == 1 and re.search(r"\stini\s", apt[0])
    assert instruction("STOPSIGNAL") == "SIGINT"
    assert not (REPO / "docker" / "init.py").exists()  # no hand-written init beside it
    assert (REPO / "docker" / "entrypoint.sh").read_text().rstrip().endswith('exec "$@"')


def test_the_default_models_int8_network_is_built_in_the_image_by_the_nodes_own_code():
    runs = [arguments for found, arguments in dockerfile_instructions() if found == "RUN"]
    built = [index for index, arguments in enumerate(runs) if "colcon build" in arguments]
    prepared = [index for index, arguments in enumerate(runs)
                if "python3 -m msfsu_perception.prepare_model models/msfsu_default.pt --precision int8" in arguments]
    assert built and prepared and built[0] < prepared[0]  # the workspace it runs from exists by then
    assert "ros2_ws/install/setup.sh" in runs[prepared[0]]
    # what it builds from is in the image: the checkpoint and its calibration frames (the build context, below)
    rules = ignore_patterns()
    assert not excluded("models/msfsu_default.pt", rules)
    assert not excluded("models/msfsu_default.pt.calibration.npz", rules)


def test_the_default_command_starts_the_graph_on_the_shipped_sample_with_a_shipped_launch_file():
    command = json.loads(instruction("CMD"))
    assert command[:3] == ["ros2", "launch", "msfsu_bringup"]
    launch_file, arguments = command[3], dict(argument.split(":=", 1) for argument in command[4:])
    assert (REPO / "msfsu_bringup" / "launch" / launch_file).is_file()
    profile = yaml.safe_load((REPO / "msfsu_bringup" / "msfsu_bringup" / "profiles" /
                              launch_file.replace(".launch.py", ".yaml")).read_text())
    required = {name for name, default in profile["arguments"].items() if default is None}
    assert required <= set(arguments) <= set(profile["arguments"])
    assert (REPO / arguments["bag"] / "metadata.yaml").is_file() and (REPO / arguments["checkpoint"]).is_file()


def test_the_base_image_is_pinned_by_digest_and_build_settings_stay_out_of_the_image():
    instructions = dockerfile_instructions()
    [base] = [arguments for instruction, arguments in instructions if instruction == "FROM"]
    assert re.fullmatch(r"ros:jazzy-ros-base@sha256:[0-9a-f]{64}", base.strip()), base
    environment = " ".join(arguments for instruction, arguments in instructions if instruction == "ENV")
    assert not re.findall(r"\bPIP_\w+", environment)  # pip's settings are the build's (ARG), not the image's
    build_arguments = [arguments.split("=")[0] for instruction, arguments in instructions if instruction == "ARG"]
    assert "PIP_BREAK_SYSTEM_PACKAGES" in build_arguments


# --- the build context (.dockerignore) -----------------------------------------------------------------------------
def ignore_patterns() -> list[tuple[bool, re.Pattern]]:
    """.dockerignore as Docker reads it (moby/patternmatcher): (exception, pattern) in order, `**` any number of
    directories, `*` and `?` within one, a leading `/` and `./` dropped."""
    rules = []
    for line in (REPO / ".dockerignore").read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        exception = line.startswith("!")
        pattern = os.path.normpath(line[1:] if exception else line).lstrip("/")
        regex = ""
        for index, part in enumerate(re.split(r"(\*\*/?|\*|\?)", pattern)):
            if part in ("**/", "**"):
                regex += "(.*/)?" if part == "**/" else ".*"
            elif part == "*":
                regex += "[^/]*"
            elif part == "?":
                regex += "[^/]"
            else:
                regex += re.escape(part)
        rules.append((exception, re.compile(regex)))
    return rules


def excluded(path: str, rules: list[tuple[bool, re.Pattern]]) -> bool:
    """Whether the context leaves `path` out: the last rule that matches it or one of its parent directories."""
    parents = [path] + [str(parent) for parent in Path(path).parents if str(parent) != "."]
    decision = False
    for exception, pattern in rules:
        if any(pattern.fullmatch(candidate) for candidate in parents):
            decision = not exception
    return decision


def build_context(rules: list[tuple[bool, re.Pattern]]) -> dict[str, int]:
    """Path -> size of every file of the working tree Docker would send (a directory left out whole is not walked:
    no exception names anything below it)."""
    exceptions = [pattern.pattern for exception, pattern in rules if exception]
    context = {}
    for directory, subdirectories, files in os.walk(REPO):
        relative = Path(directory).relative_to(REPO)
        for name in list(subdirectories):
            path = str(relative / name) if str(relative) != "." else name
            if excluded(path, rules) and not any(p.startswith(re.escape(path.split("/")[0])) or p.startswith(".*")
                                                 or p.startswith("[^/]*") for p in exceptions):
                subdirectories.remove(name)
        for name in files:
            path = str(relative / name) if str(relative) != "." else name
            if not excluded(path, rules):
                context[path] = (Path(directory) / name).lstat().st_size
    return context


def test_the_build_context_holds_what_the_image_needs_and_nothing_else():
    rules = ignore_patterns()

    def image_part(path: str) -> bool:
        """The packages, their workspace links, the Docker files, the sample bag, the models and their gate records."""
        return bool(path.startswith(("msfsu_", "carla_msgs/", "ros2_ws/src/", "docker/", "bags/sample/"))
                    or re.fullmatch(r"models/[^/]+\.pt|models/msfsu_default\.pt\.calibration\.npz"
                                    r"|models/[^/]+\.deploy/[^/]+\.json", path))

    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True, check=True).stdout.split()
    needed = [path for path in tracked if image_part(path)]
    assert "docker/entrypoint.sh" in needed and "models/msfsu_default.pt" in needed
    assert "ros2_ws/src/msfsu_perception" in needed and "carla_msgs/msg/CarlaEgoVehicleControl.msg" in needed
    assert [path for path in needed if excluded(path, rules)] == []
    for path in (".git/HEAD", "checkpoints/x.pt", "runs/demo/x", "data/cache/x", ".venv/bin/python", "build/x",
                 "docs/index.md", "tests/test_x.py", "benchmarks/x.py", "scripts/x.sh", "README.md",
                 "msfsu_perception/msfsu_perception/__pycache__/x.pyc", "msfsu_perception/msfsu_perception.egg-info/x",
                 "models/msfsu_default.pt.deploy/x-v3-fp32.onnx", "models/x.pt.calibration.npz"):
        assert excluded(path, rules), path
    context = build_context(rules)
    assert sorted(path for path in context if not image_part(path)) == []
    assert sum(context.values()) < 200e6, sum(context.values())  # ~115 MB: the models and the sample bag


# --- docker stop: tini passes the stop signal to every node -------------------------------------------------------
def image_entrypoint() -> list[str]:
    """The Dockerfile's ENTRYPOINT with the image's /opt/msfsu read as this repository."""
    return [part.replace("/opt/msfsu", str(REPO)) for part in json.loads(instruction("ENTRYPOINT"))]


def stop_signal() -> signal.Signals:
    """The signal `docker stop` sends: the Dockerfile's STOPSIGNAL (Docker's default SIGTERM without one)."""
    found = [arguments for name, arguments in dockerfile_instructions() if name == "STOPSIGNAL"]
    return signal.Signals[found[0].strip()] if found else signal.SIGTERM


@pytest.mark.skipif(not Path("/usr/bin/tini").is_file(),
                    reason="no /usr/bin/tini (the image's first process; Debian and Ubuntu package it: apt-get install "
                           "tini, which make setup does where it runs as root)")
@pytest.mark.parametrize("how", ["ros2 run", "launcher"])
def test_docker_stop_ends_every_node_cleanly_through_the_entrypoint(tmp_path, how):
    """The container's first process stood in for by the ENTRYPOINT, tini then the entry point (sourcing nothing: the
    environment is a colcon install with Jazzy's `ros2 run`), run as `docker run IMAGE COMMAND` runs it; the stop
    signal as `docker stop` sends it. tini ends when the command ends; in a container the kernel then kills whatever
    is left, so the command must have waited for its nodes: every node is gone when tini has ended, and the recorder
    closed its bag (it got the signal and had time to shut down)."""
    recorded = tmp_path / "recorded"
    env = ros2cli_environment(tmp_path, "msfsu_bringup", ["bag_player", "bag_recorder"])
    env.update(MSFSU_ROS_SETUP=os.devnull, MSFSU_WORKSPACE_SETUP=os.devnull,
               PATH=f"{env['PATH']}{os.pathsep}{Path(sys.executable).parent}")  # python3: the venv's, as the image's
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    if how == "ros2 run":
        command = ["ros2", "run", "msfsu_bringup", "bag_recorder", "--ros-args", "-p", f"output:={recorded}",
                   "-p", f"topics:=[{topics.NAVIGATION_COMMAND}]"]
        up = "recording into"
    else:
        bag = tmp_path / "input"
        write_synthetic_bag(bag, n_frames=30, split="test")
        profile = tmp_path / "play_and_record.yaml"
        profile.write_text(yaml.safe_dump({"nodes": [
            {"name": "bag_player", "package": "msfsu_bringup", "executable": "bag_player",
             "parameters": {"bag": str(bag), "rate": 0.1, "wait_for": [topics.NAVIGATION_COMMAND],
                            "wait_timeout": 60.0}},
            {"name": "bag_recorder", "package": "msfsu_bringup", "executable": "bag_recorder",
             "parameters": {"output": str(recorded), "topics": [topics.NAVIGATION_COMMAND]}}]}))
        command = ["python3", "-m", "msfsu_bringup", str(profile)]
        up = STARTED_MESSAGE
    log = tmp_path / "container.log"
    with log.open("w") as output:
        container = subprocess.Popen(image_entrypoint() + command, env=env, stdout=output, stderr=subprocess.STDOUT)
    nodes: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while up not in log.read_text():
            assert container.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.2)
        nodes = descendants(container.pid)
        assert len(nodes) >= (2 if how == "ros2 run" else 3)  # ros2 run + recorder; launcher + player + recorder
        container.send_signal(stop_signal())
        assert container.wait(timeout=30) == 0, log.read_text()  # the command's own exit status
        assert not alive(nodes), log.read_text()  # nothing left for the kernel to kill
    finally:
        for pid in alive(nodes) | ({container.pid} if container.poll() is None else set()):
            os.kill(pid, signal.SIGKILL)
    assert (recorded / METADATA_FILE).is_file(), log.read_text()
    assert "closed bag with" in log.read_text()


# --- torch: the CPU build or no image ------------------------------------------------------------------------------
def fake_wheel(directory: Path, name: str, version: str, requires: tuple[str, ...] = ()) -> None:
    """A wheel pip resolves like any other: its metadata only (a PEP 503 page lists it, see simple_index)."""
    directory.mkdir(parents=True, exist_ok=True)
    info = f"{name}-{version}.dist-info"
    files = {f"{info}/METADATA": "Metadata-Version: 2.1\nName: " + name + "\nVersion: " + version + "\n"
             + "".join(f"Requires-Dist: {requirement}\n" for requirement in requires),
             f"{info}/WHEEL": "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n"}
    files[f"{info}/RECORD"] = "".join(f"{path},,\n" for path in files) + f"{info}/RECORD,,\n"
    with zipfile.ZipFile(directory / f"{name}-{version}-py3-none-any.whl", "w") as wheel:
        for path, text in files.items():
            wheel.writestr(path, text)


def simple_index(root: Path) -> str:
    """PEP 503 pages over the wheels in root/<project>/; the index's file:// URL."""
    for project in (path for path in root.iterdir() if path.is_dir()):
        links = "".join(f'<a href="{wheel.name}">{wheel.name}</a>\n' for wheel in sorted(project.glob("*.whl")))
        (project / "index.html").write_text(f"<html><body>\n{links}</body></html>\n")
    return root.as_uri()


@pytest.mark.parametrize("cpu_build", [True, False], ids=["cpu-build-there", "cpu-build-missing"])
def test_the_image_takes_torch_from_the_cpu_index_or_fails(tmp_path, cpu_build):
    """docker/install_requirements.sh against local stand-ins of PyTorch's CPU index and PyPI: PyPI has the pinned
    torch (the CUDA build, which pulls nvidia-* packages); the CPU index has its +cpu build, or only an older one."""
    cpu, pypi = tmp_path / "cpu", tmp_path / "pypi"
    fake_wheel(cpu / "torch", "torch", "2.13.0+cpu" if cpu_build else "2.12.0+cpu")
    fake_wheel(pypi / "torch", "torch", "2.13.0", requires=("nvidia-cublas-cu12",))
    fake_wheel(pypi / "nvidia-cublas-cu12", "nvidia_cublas_cu12", "12.0.0")
    fake_wheel(pypi / "tinyutil", "tinyutil", "1.0")
    requirements = tmp_path / "requirements.txt"
    requirements.write_text("# the image's pins\ntorch==2.13.0\ntinyutil==1.0\n")
    report = tmp_path / "report.json"
    env = dict(pip_environment(), TORCH_INDEX_URL=simple_index(cpu), PYPI_INDEX_URL=simple_index(pypi),
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")  # pip3: this Python's
    result = subprocess.run([str(REPO / "docker" / "install_requirements.sh"), str(requirements), "--dry-run",
                             "--report", str(report), "--quiet"], env=env, capture_output=True, text=True, timeout=300)
    if not cpu_build:
        assert result.returncode == 1 and not report.exists()
        assert result.stderr.strip().splitlines()[-1] == (
            f"install_requirements.sh: the resolution failed; if pip says torch has no matching distribution, "
            f"{cpu.as_uri()} has no 2.13.0+cpu build for this Python: pin a torch version it has (never PyPI's, the "
            "CUDA build)")
        return
    assert result.returncode == 0, result.stderr
    resolved = {item["metadata"]["name"]: (item["metadata"]["version"], item["download_info"]["url"])
                for item in json.loads(report.read_text())["install"]}
    assert resolved == {"torch": ("2.13.0+cpu", (cpu / "torch" / "torch-2.13.0+cpu-py3-none-any.whl").as_uri()),
                        "tinyutil": ("1.0", (pypi / "tinyutil" / "tinyutil-1.0-py3-none-any.whl").as_uri())}


@pytest.mark.parametrize("installed, passes", [((), True), ((("torch", "2.13.0"),), False),
                                                ((("nvidia_cublas_cu12", "12.0.0"),), False)],
                         ids=["this-venv", "pypi-torch", "a-cuda-package"])
def test_the_images_last_check_refuses_any_cuda_build(tmp_path, installed, passes):
    """docker/check_torch_cpu.py in this venv (torch's CPU build), and with a distribution of PyPI's torch or an
    nvidia-* package found first on the path."""
    for name, version in installed:
        info = tmp_path / f"{name}-{version}.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    result = subprocess.run([sys.executable, str(REPO / "docker" / "check_torch_cpu.py")], capture_output=True,
                            text=True, env=dict(os.environ, PYTHONPATH=str(tmp_path)), timeout=60)
    assert (result.returncode == 0) == passes, result.stdout + result.stderr
    if not passes:
        assert result.stderr.startswith("check_torch_cpu.py: torch ") and "not PyTorch's CPU build" in result.stderr
