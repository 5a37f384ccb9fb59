"""No import cycle among the project's modules (the msfsu_* packages), lazy imports included.

Every import a module can make counts: top-level, inside functions, `__import__("...")` and
`importlib.import_module("...")` with a literal name, relative imports resolved. A cycle fails the test
with the modules of the cycle named in import order.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def project_modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every module of the packages `msfsu_*/msfsu_*/` (tests excluded)."""
    modules = {}
    for package in sorted(root.glob("msfsu_*/msfsu_*/__init__.py")):
        base = package.parent
        for path in sorted(base.rglob("*.py")):
            parts = path.relative_to(base.parent).with_suffix("").parts
            if "test" in parts or "tests" in parts:
                continue
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def _imported_names(tree: ast.AST, module: str, is_package: bool) -> list[str]:
    """Every dotted name the module's code may import: `import a.b`, `from a import b` (as `a.b` and `a`),
    relative imports resolved against `module`, and literal `__import__` / `importlib.import_module` calls."""
    names = []
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            names.append(base)
            names += [f"{base}.{alias.name}" for alias in node.names]
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str) and _is_dynamic_import(node.func)):
            names.append(node.args[0].value)
    return names


def _is_dynamic_import(func: ast.expr) -> bool:
    return ((isinstance(func, ast.Name) and func.id in ("__import__", "import_module"))
            or (isinstance(func, ast.Attribute) and func.attr == "import_module"))


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports (a name that is not a module counts as its package)."""
    graph = {}
    for module, path in modules.items():
        targets = set()
        for name in _imported_names(ast.parse(path.read_text()), module, path.name == "__init__.py"):
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name and name != module:
                targets.add(name)
        graph[module] = targets
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as [a, b, ..., a] (depth-first, modules in sorted order), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(module: str) -> list[str] | None:
        state[module] = 1
        path.append(module)
        for target in sorted(graph.get(module, ())):
            if state.get(target) == 1:
                return path[path.index(target):] + [target]
            if target not in state:
                cycle = visit(target)
                if cycle:
                    return cycle
        path.pop()
        state[module] = 2
        return None

    for module in sorted(graph):
        if module not in state:
            cycle = visit(module)
            if cycle:
                return cycle
    return None


def test_a_cycle_through_a_lazy_import_is_found(tmp_path):
    package = tmp_path / "msfsu_demo" / "msfsu_demo"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from msfsu_demo.b import thing\n")
    (package / "b.py").write_text("def thing():\n    return __import__('msfsu_demo.a').a\n")
    (package / "c.py").write_text("from . import a\n")
    graph = import_graph(project_modules(tmp_path))
    assert graph["msfsu_demo.c"] == {"msfsu_demo", "msfsu_demo.a"}
    assert find_cycle(graph) == ["msfsu_demo.a", "msfsu_demo.b", "msfsu_demo.a"]


def test_no_module_of_the_project_is_part_of_an_import_cycle():
    cycle = find_cycle(import_graph(project_modules()))
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def folder_graph(graph: dict[str, set[str]], modules: dict[str, Path]) -> dict[str, set[str]]:
    """Folder -> the other folders its modules import. A folder is a subpackage of a project package (closed_loop/,
    records/): its modules and its __init__ count as one; a module directly in a project package stands alone."""
    def folder(module: str) -> str:
        package = module if modules[module].name == "__init__.py" else module.rpartition(".")[0]
        return package if "." in package else module

    folders: dict[str, set[str]] = {}
    for module, targets in graph.items():
        mine = folder(module)
        folders.setdefault(mine, set()).update(folder(target) for target in targets if folder(target) != mine)
    return folders


def test_a_cycle_between_two_folders_is_found_where_no_module_cycle_is(tmp_path):
    package = tmp_path / "msfsu_demo" / "msfsu_demo"
    for folder in ("records", "deploy"):
        (package / folder).mkdir(parents=True)
        (package / folder / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "records" / "page.py").write_text("from msfsu_demo.deploy.damage import Damage\n")
    (package / "deploy" / "damage.py").write_text("Damage = float\n")
    (package / "deploy" / "search.py").write_text("from msfsu_demo.records.page import x\n")
    modules = project_modules(tmp_path)
    graph = import_graph(modules)
    assert find_cycle(graph) is None
    assert find_cycle(folder_graph(graph, modules)) == ["msfsu_demo.deploy", "msfsu_demo.records", "msfsu_demo.deploy"]


def test_no_folder_of_the_project_imports_a_folder_that_imports_it_back():
    modules = project_modules()
    cycle = find_cycle(folder_graph(import_graph(modules), modules))
    assert cycle is None, "folder import cycle: " + " -> ".join(cycle or [])
