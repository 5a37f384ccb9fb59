"""Starts the node graph from a YAML profile: `python -m msfsu_bringup <profile> --arg key=value`.

Each node runs as its own process, started from the file `ros2 run <package> <executable>` would exec:
lib/<package>/<executable> in the first AMENT_PREFIX_PATH prefix whose ament index lists the package (a colcon
or apt install), else the console script next to this interpreter (a pip install). The launcher never starts
`ros2 run` itself: Jazzy's wrapper ignores SIGINT and forwards no signal, so a signal sent to it never reaches
the node. Parameters go through a generated --params-file (types preserved), remappings through `-r`.
Ctrl-C/SIGTERM are forwarded to every node; when any node exits (e.g. the bag player at the end of the bag)
the others are stopped, and the exit code is the first non-zero one. Nodes get SIGTERM from the kernel should
the launcher itself die (msfsu_common.processes): no node outlives it, no participant's Fast DDS segment is
left in /dev/shm.

Managed (lifecycle) nodes, `lifecycle: true` in the profile, are brought to `--lifecycle` (default active:
configured, then activated, as launch_ros's autostart does; `inactive`: configured only; `unconfigured`: left for
`ros2 lifecycle set`) through their lifecycle_msgs services (msfsu_bringup.lifecycle). A node that refuses a
transition ends the launch with exit code 1; its own log line says why.

Profile format:
    description: text
    arguments: {name: default}          # null = required; used as ${name} in parameters/remappings;
                                        # {product: KEY}: the product's (msfsu_bringup.product, product.yaml)
    nodes:
      - {name: perception, package: msfsu_perception, executable: perception, lifecycle: true,
         parameters: {checkpoint: ${checkpoint}, command_wait: {if: ${rate}, then: 0.0, else: 0.1}},
         remappings: {/from: /to}, condition: ${flag}}

A node's `parameters` may be a list of mappings, merged in order (a later one wins), as launch_ros's `parameters`:
`parameters: [{use_sim_time: true}, ${camera}]` adds a mapping argument's entries (`--arg 'camera={fov: 90}'`).

A mapping with exactly the keys if, then, else is a conditional value: `then` where `if` is truthy, else `else`
(truthy as a node's `condition`: a whole `${name}` keeps the argument's type, so 0.0, false and "" are false).
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from msfsu_bringup.lifecycle import TARGETS, TRANSITIONS, LifecycleError, LifecycleManager
from msfsu_common.processes import die_with_parent
from msfsu_common.ros_env import configure_ros_environment

PROFILE_DIR = Path(__file__).parent / "profiles"
AMENT_PACKAGES = Path("share") / "ament_index" / "resource_index" / "packages"  # one marker file per package
STOP_TIMEOUT_S = 10.0
_ARGUMENT = re.compile(r"\$\{(\w+)\}")
CONDITIONAL_KEYS = frozenset({"if", "then", "else"})


class ProfileError(ValueError):
    pass


@dataclass(frozen=True)
class NodeSpec:
    name: str
    package: str
    executable: str
    parameters: dict[str, Any] = field(default_factory=dict)
    remappings: dict[str, str] = field(default_factory=dict)
    condition: Any = True  # the node starts only if this is truthy (e.g. `${record}` non-empty)
    lifecycle: bool = False  # a managed node: the launcher drives its transitions (msfsu_bringup.lifecycle)


def shipped_profiles() -> list[str]:
    """The names of the profiles shipped with msfsu_bringup, sorted."""
    return sorted(p.stem for p in PROFILE_DIR.glob("*.yaml"))


def profiles_help() -> str:
    """Every shipped profile with the first clause of its description, for the launcher's help."""
    lines = ["shipped profiles:"]
    for name in shipped_profiles():
        try:
            description = str(yaml.safe_load((PROFILE_DIR / f"{name}.yaml").read_text()).get("description", ""))
        except (OSError, yaml.YAMLError, AttributeError) as error:
            description = f"(unreadable: {error})"
        lines.append(f"  {name:<11} {re.split(r'[.:;] ', description)[0].rstrip('.')}")
    return "\n".join(lines)


def profile_path(profile: str) -> Path:
    """A profile name shipped with msfsu_bringup (`replay`) or a path to a YAML file."""
    path = Path(profile)
    if path.suffix in (".yaml", ".yml") and path.is_file():
        return path
    shipped = PROFILE_DIR / f"{profile}.yaml"
    if not shipped.is_file():
        raise ProfileError(f"no profile '{profile}' (shipped: {', '.join(shipped_profiles())}; or give a .yaml path)")
    return shipped


def _typed(value: str, default: Any) -> Any:
    """CLI text -> the type of the argument's default (ROS rejects 2 for a double parameter).

    List and mapping arguments are given as YAML flow text: `--arg 'topics=[/a, /b]'`, `--arg 'remap={/a: /b}'`.
    """
    if isinstance(default, bool):
        return value.lower() in ("1", "true", "yes", "on")
    if isinstance(default, (int, float)):
        return type(default)(value)
    if isinstance(default, (list, dict)):
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError as error:
            raise ProfileError(f"'{value}' is not YAML flow text: {error}") from error
        parsed = type(default)() if parsed is None else parsed
        if not isinstance(parsed, type(default)):
            raise ProfileError(f"'{value}' is not a YAML {type(default).__name__} like the default {default!r}")
        return parsed
    return value


def _substitute(value: Any, arguments: dict[str, Any]) -> Any:
    """`value` with every `${name}` replaced by its argument and every conditional value by its chosen branch."""
    if isinstance(value, dict) and value.keys() == CONDITIONAL_KEYS:
        return _substitute(value["then" if _substitute(value["if"], arguments) else "else"], arguments)
    if isinstance(value, dict):
        return {key: _substitute(item, arguments) for key, item in value.items()}
    if isinstance(value, list):
        return [_substitute(item, arguments) for item in value]
    if isinstance(value, str):
        whole = _ARGUMENT.fullmatch(value)
        if whole:
            return arguments[whole.group(1)]
        return _ARGUMENT.sub(lambda match: str(arguments[match.group(1)]), value)
    return value


def _node_spec(spec: dict[str, Any], path: Path) -> NodeSpec:
    """A node of a substituted profile; a list of parameter mappings is merged in order."""
    parameters = spec.get("parameters")
    if isinstance(parameters, list):
        if not all(isinstance(part, dict) for part in parameters):
            raise ProfileError(f"{path.name}: the parameters of node {spec.get('name')!r} are a list whose items are "
                               f"not all mappings: {parameters!r}")
        spec = {**spec, "parameters": {key: value for part in parameters for key, value in part.items()}}
    return NodeSpec(**spec)


def _product_defaults(defaults: dict[str, Any], path: Path) -> dict[str, Any]:
    """The arguments' defaults with each `{product: KEY}` replaced by the product's value (msfsu_bringup.product)."""
    from msfsu_bringup.product import load_product

    product = None
    resolved = {}
    for name, default in defaults.items():
        if isinstance(default, dict) and default.keys() == {"product"}:
            product = product or load_product()
            try:
                default = product.value(default["product"])
            except KeyError as error:
                raise ProfileError(f"{path.name}: argument {name}: {error.args[0]}") from None
        resolved[name] = default
    return resolved


def read_profile(path: Path) -> dict[str, Any]:
    """The profile file as YAML reads it, each argument default `{product: KEY}` replaced by the product's value;
    ProfileError (one line) where it is no YAML or names no field of the product."""
    try:
        profile = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as error:
        raise ProfileError(f"{path} is not valid YAML (quote ${{...}} inside {{}} mappings): {error}") from error
    if profile.get("arguments"):
        profile["arguments"] = _product_defaults(profile["arguments"], path)
    return profile


def argument_text(default: Any) -> str:
    """An argument's default as the text `--arg NAME=TEXT` (or a launch argument) gives it back (`_typed` reads it)."""
    if isinstance(default, bool):
        return str(default).lower()
    if isinstance(default, (list, dict)):
        return yaml.safe_dump(default, default_flow_style=True, width=1 << 20).strip()
    return str(default)


def load_profile(path: Path, given: dict[str, str]) -> tuple[str, list[NodeSpec]]:
    profile = read_profile(path)
    defaults: dict[str, Any] = profile.get("arguments") or {}
    unknown = set(given) - set(defaults)
    if unknown:
        raise ProfileError(f"unknown argument(s) {sorted(unknown)}; {path.name} takes {sorted(defaults)}")
    arguments = {name: _typed(given[name], default) if name in given else default for name, default in defaults.items()}
    missing = [name for name, value in arguments.items() if value is None]
    if missing:
        raise ProfileError(f"profile {path.name} needs " + " ".join(f"--arg {name}=..." for name in missing))
    specs = [_node_spec(_substitute(spec, arguments), path) for spec in profile.get("nodes") or []]
    nodes = [spec for spec in specs if spec.condition]
    if not nodes:
        raise ProfileError(f"profile {path.name} starts no node")
    return profile.get("description", ""), nodes


def ament_executable(package: str, executable: str, ament_prefix_path: str) -> Path | None:
    """lib/<package>/<executable> in the first prefix of `ament_prefix_path` whose ament index lists `package`
    (the file `ros2 run` execs); None where no prefix lists it."""
    for prefix in filter(None, ament_prefix_path.split(os.pathsep)):
        if (Path(prefix) / AMENT_PACKAGES / package).is_file():
            return Path(prefix) / "lib" / package / executable
    return None


def node_executable(spec: NodeSpec, environ: Mapping[str, str]) -> Path:
    """The file a node runs from: its package's in the ament index of `environ`, else the console script next to
    this interpreter."""
    executable = ament_executable(spec.package, spec.executable, environ.get("AMENT_PREFIX_PATH", ""))
    if executable is None:
        executable = Path(sys.executable).parent / spec.executable
    if not (executable.is_file() and os.access(executable, os.X_OK)):
        raise ProfileError(f"executable '{spec.executable}' of {spec.package} is not installed ({executable})")
    return executable


def node_parameters(spec: NodeSpec) -> dict[str, Any]:
    """The parameters a node is given: an empty list has no ROS type (the node would read None), so it is left out
    and the declared default applies."""
    return {name: value for name, value in spec.parameters.items() if value != []}


def node_command(spec: NodeSpec, params_dir: Path, environ: Mapping[str, str] = os.environ) -> list[str]:
    params_file = params_dir / f"{spec.name}.yaml"
    params_file.write_text(yaml.safe_dump({"/**": {"ros__parameters": node_parameters(spec)}}))
    command = [str(node_executable(spec, environ)), "--ros-args", "-r", f"__node:={spec.name}",
               "--params-file", str(params_file)]
    for source, target in spec.remappings.items():
        command += ["-r", f"{source}:={target}"]
    return command


def run(nodes: list[NodeSpec], lifecycle_target: str = "active") -> int:
    env = configure_ros_environment(dict(os.environ))
    stop_requested = False
    managed = [spec.name for spec in nodes if spec.lifecycle]
    manager: LifecycleManager | None = None

    def request_stop(signum, frame) -> None:
        nonlocal stop_requested
        stop_requested = True

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    processes: dict[str, subprocess.Popen] = {}
    exit_code = 0
    try:
        with tempfile.TemporaryDirectory(prefix="msfsu_bringup_") as params_dir:
            # every command first: a node that cannot start (not installed) is refused before any other starts
            commands = {spec.name: node_command(spec, Path(params_dir), env) for spec in nodes}
            for spec in nodes:
                command = commands[spec.name]
                print(f"[bringup] starting {spec.name}: {' '.join(command)}", flush=True)
                processes[spec.name] = subprocess.Popen(command, env=env, start_new_session=True,
                                                        preexec_fn=die_with_parent())
            if managed and TRANSITIONS[lifecycle_target]:
                manager = LifecycleManager(managed, lifecycle_target)
            elif managed:
                print(_left_inactive(managed, lifecycle_target), flush=True)
            while not stop_requested:
                exited = {name: p.returncode for name, p in processes.items() if p.poll() is not None}
                if exited:
                    for name, code in exited.items():
                        print(f"[bringup] {name} exited with code {code}", flush=True)
                    exit_code = next((code for code in exited.values() if code != 0), 0)
                    break
                if manager is None:
                    time.sleep(0.1)
                    continue
                try:
                    for line in manager.poll(0.1):
                        print(f"[bringup] {line}", flush=True)
                except LifecycleError as error:
                    print(f"[bringup] {error}: stopping the launch", flush=True)
                    exit_code = 1
                    break
                if manager.done:
                    print(f"[bringup] {', '.join(managed)}: {lifecycle_target}", flush=True)
                    if lifecycle_target != "active":
                        print(_left_inactive(managed, lifecycle_target), flush=True)
                    manager.close()
                    manager = None
            exit_code = _stop_all(processes) or exit_code
    finally:
        if manager is not None:
            manager.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return exit_code


def _left_inactive(managed: list[str], target: str) -> str:
    """What a launch that leaves its managed nodes short of active waits for, and how to go on."""
    steps = " then ".join(f"`ros2 lifecycle set /{name} {step}`" for name in managed
                          for step in TRANSITIONS["active"][len(TRANSITIONS[target]):])
    return (f"[bringup] {', '.join(managed)} left {target} (--lifecycle {target}): a managed node subscribes once "
            f"active ({steps}); a node that waits for its subscription (the bag player's wait_for) waits until then")


def _stop_all(processes: dict[str, subprocess.Popen]) -> int:
    """SIGINT every running node, escalate to SIGTERM/SIGKILL; return a non-zero code if one was needed."""
    running = [p for p in processes.values() if p.poll() is None]
    for process in running:
        process.send_signal(signal.SIGINT)
    escalated = 0
    for escalation in (signal.SIGTERM, signal.SIGKILL):
        deadline = time.monotonic() + STOP_TIMEOUT_S
        while any(p.poll() is None for p in running) and time.monotonic() < deadline:
            time.sleep(0.05)
        for name, process in processes.items():
            if process.poll() is None:
                print(f"[bringup] {name} did not stop, sending {escalation.name}", flush=True)
                process.send_signal(escalation)
                escalated = 1
    for process in running:
        process.wait()
    return escalated


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m msfsu_bringup", description="Start the MSFSU node graph.",
                                     epilog=profiles_help(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("profile", help=f"shipped profile name ({', '.join(shipped_profiles())}) or a YAML path")
    parser.add_argument("--arg", action="append", default=[], metavar="NAME=VALUE", help="profile argument")
    parser.add_argument("--dry-run", action="store_true", help="print the node commands and exit")
    parser.add_argument("--lifecycle", choices=TARGETS, default="active",
                        help="bring the profile's managed nodes to this state: active (configure, activate), inactive "
                             "(configure) or unconfigured (leave them for `ros2 lifecycle set`)")
    options = parser.parse_args(argv)
    try:
        given = dict(item.split("=", 1) for item in options.arg)
        description, nodes = load_profile(profile_path(options.profile), given)
        if options.dry_run:
            with tempfile.TemporaryDirectory() as params_dir:
                for spec in nodes:
                    print(" ".join(node_command(spec, Path(params_dir))))
            return 0
    except (ProfileError, ValueError) as error:
        print(f"bringup: {error}", file=sys.stderr)
        return 2
    print(f"[bringup] {options.profile}: {description}", flush=True)
    try:
        return run(nodes, options.lifecycle)
    except ProfileError as error:  # a node's executable missing: refused before any node started
        print(f"bringup: {error}", file=sys.stderr)
        return 2
