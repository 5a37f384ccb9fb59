"""`msfsu-node-parameters`: write the parameter tables of docs/nodes.md from the nodes' settings dataclasses (never
typed by hand).

    msfsu-node-parameters           # rewrite the block of docs/nodes.md
    msfsu-node-parameters --check   # exit 1 if docs/nodes.md differs from the code (a test runs this)

The block is `<!-- generated:node-parameters -->` ... `<!-- /generated:node-parameters -->`: per node, one row per
parameter (msfsu_common.params declares them: live first, then read-only), with its default, its valid values and
its description, all read from the classes each node hands to NodeParameters.
"""

from __future__ import annotations

import importlib
import json
import re
import sys
from typing import Any

from msfsu_common.settings import Setting, parameters
from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT
from msfsu_evaluation.reports.blocks import rewrite_page

PROG = "msfsu-node-parameters"
PAGE = ROOT / "docs" / "nodes.md"
BLOCK = re.compile(r"(<!-- generated:node-parameters -->\n).*?(<!-- /generated:node-parameters -->)", re.S)
# node name, module, its live settings class, its read-only settings class (None: none)
NODES = (
    ("perception", "msfsu_perception.perception_node", "PerceptionSettings", "PerceptionStartup"),
    ("control", "msfsu_control.control_node", "ControlSettings", "ControlStartup"),
    ("aeb", "msfsu_control.aeb_node", "AebSettings", "AebCamera"),
    ("route", "msfsu_control.route_node", "RouteSettings", None),
    ("sim_bridge", "msfsu_sim.bridge_node", "BridgeSettings", "BridgeStartup"),
    ("bag_player", "msfsu_bringup.bag_player", "PlayerSettings", "PlayerStartup"),
    ("bag_recorder", "msfsu_bringup.bag_recorder", "RecorderSettings", "RecorderStartup"),
)


def literal(value: Any) -> str:
    """A default as a `--ros-args -p name:=value` would write it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (str, tuple)):
        return json.dumps(list(value) if isinstance(value, tuple) else value)
    return repr(value)


def valid_values(spec: Setting) -> str:
    if spec.choices:
        return ", ".join(f"`{choice}`" for choice in spec.choices)
    return f"{spec.low!r} to {spec.high!r}" if spec.low is not None else ""


def cell(text: str) -> str:
    """`text` as a markdown table cell shows it (no HTML tags, no column breaks)."""
    return text.replace("<", "&lt;").replace("|", "\\|")


def table(node: str, module_name: str, live: str, read_only: str | None) -> str:
    module = importlib.import_module(module_name)
    rows = [f"### `{node}`", "", "| parameter | kind | default | valid values | meaning |", "| --- | --- | --- | --- | --- |"]
    for kind, class_name in (("live", live), ("read-only", read_only)):
        for parameter in parameters(getattr(module, class_name)) if class_name else []:
            rows.append(f"| `{parameter.name}` | {kind} | `{literal(parameter.default)}` | "
                        f"{valid_values(parameter.setting)} | {cell(parameter.setting.description)} |")
    return "\n".join(rows)


def render(text: str) -> str:
    count = len(BLOCK.findall(text))
    if count != 1:
        raise ValueError(f"{PAGE.name} needs exactly one node-parameters block, found {count}")
    tables = "\n\n".join(table(*node) for node in NODES)
    return BLOCK.sub(lambda match: f"{match.group(1)}{tables}\n{match.group(2)}", text)


def main(argv: list[str] | None = None) -> int:
    return rewrite_page(PAGE, render, PROG, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    sys.exit(main())
