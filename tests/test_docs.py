"""The README and docs/ stay true: their links resolve, the README's commands start, the README stays short, and
the package layering docs/architecture.md states is the one the code has."""

from __future__ import annotations

import ast
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
README_LIMIT = 250  # lines: the README is the front door, the reference is in docs/
PAGES = [README, *sorted((ROOT / "docs").glob("*.md")), ROOT / "docs" / "results" / "README.md"]

_FENCE = re.compile(r"^```.*?^```", re.S | re.M)
_INLINE_CODE = re.compile(r"`[^`\n]*`")
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
_HEADING = re.compile(r"^#{1,6} +(.+?) *#*$", re.M)


def _prose(text: str) -> str:
    """`text` without code blocks and inline code (their brackets are no links)."""
    return _INLINE_CODE.sub("", _FENCE.sub("", text))


def anchors(text: str) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation dropped, spaces as hyphens, -N for
    repeats."""
    found: set[str] = set()
    for heading in _HEADING.findall(_FENCE.sub("", text)):
        slug = re.sub(r"[^\w\- ]", "", heading.replace("`", "").lower()).replace(" ", "-")
        anchor, n = slug, 0
        while anchor in found:
            n += 1
            anchor = f"{slug}-{n}"
        found.add(anchor)
    return found


def broken_links(page: Path, root: Path = ROOT) -> list[str]:
    """Every relative link or image of `page` whose file, or whose anchor in a markdown file, is not there."""
    text = page.read_text()
    problems = []
    for target in _LINK.findall(_prose(text)):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):
            continue  # https:, mailto: ...
        path, _, anchor = target.partition("#")
        resolved = (page.parent / path).resolve() if path else page
        if not resolved.exists():
            problems.append(f"{page.relative_to(root)}: {target}: no such file")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved.read_text()):
            problems.append(f"{page.relative_to(root)}: {target}: no heading with that anchor")
    return problems


def test_the_anchors_are_githubs():
    text = "# Real time on the road\n## `msfsu-eval-bag`: open loop\n## 2026-11-25: factor 0.5\n## Tests\n## Tests\n"
    assert anchors(text) == {"real-time-on-the-road", "msfsu-eval-bag-open-loop", "2026-11-25-factor-05", "tests",
                             "tests-1"}


def test_a_missing_file_or_anchor_is_found(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("# A\n## Speed\n")
    page = tmp_path / "docs" / "b.md"
    page.write_text("[ok](a.md#speed) [file](c.md) ![image](img.png) [anchor](a.md#sped) `[code](x.md)`\n"
                    "[web](https://example.org) [self](#b)\n# B\n```\n[fenced](y.md)\n```\n")
    assert broken_links(page, tmp_path) == ["docs/b.md: c.md: no such file", "docs/b.md: img.png: no such file",
                                            "docs/b.md: a.md#sped: no heading with that anchor"]


@pytest.mark.parametrize("page", PAGES, ids=lambda page: page.relative_to(ROOT).as_posix())
def test_every_relative_link_and_image_resolves(page):
    assert broken_links(page) == []


def test_the_readme_stays_under_its_limit():
    lines = README.read_text().count("\n")
    assert lines <= README_LIMIT, f"README.md has {lines} lines (at most {README_LIMIT}): move reference to docs/"


def use_it_commands() -> list[str]:
    """The command lines of the README's "Use it" section (continued lines joined, comments dropped)."""
    section = README.read_text().split("\n## Use it\n", 1)[1].split("\n## ", 1)[0]
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", section, re.S):
        for command in block.replace("\\\n", " ").splitlines():
            command = command.split(" # ", 1)[0].strip()
            if command and not command.startswith("#"):
                commands.append(" ".join(command.split()))
    return commands


def _help_invocation(command: str) -> tuple[list[str], list[str]]:
    """The process that shows `command`'s help, and the options the command uses (its help must name them).
    `make T` is a dry run of T; `docker build ... && docker run ... IMAGE CMD` is CMD run here (the image needs a
    Docker engine, which CI has not): `ros2 run PACKAGE EXECUTABLE` is the console script, `python3` the venv's."""
    bin_dir = Path(sys.executable).parent
    if command.startswith("docker "):
        assert (ROOT / "Dockerfile").is_file()
        run = shlex.split(command.split("&&")[-1])
        assert run[:2] == ["docker", "run"], command
        options_end = next(i for i, word in enumerate(run[2:], 2) if not word.startswith("-"))
        words = run[options_end + 1:]  # after the image's name
        if words[:2] == ["ros2", "run"]:
            words = [str(bin_dir / words[3]), *words[4:]]
    else:
        words = shlex.split(command)
    if words[0] == "make":
        return ["make", "-n", *words[1:]], []
    options = [word.split("=")[0] for word in words[1:] if word.startswith("--") and word != "--help"]
    if words[0] in ("python", "python3"):
        assert words[1] == "-m", command
        return [sys.executable, "-m", words[2], "--help"], options
    program = words[0] if Path(words[0]).is_absolute() else str(bin_dir / words[0])
    return [program, "--help"], options


def test_every_command_of_the_use_it_section_starts_and_knows_its_options():
    commands = use_it_commands()
    programs = {shlex.split(command)[0] for command in commands}
    assert {"msfsu-eval-bag", "python", "msfsu-train", "msfsu-benchmark", "make", "docker"} <= programs, commands
    helps: dict[tuple[str, ...], list[tuple[str, list[str]]]] = {}  # one run of each help
    for command in commands:
        invocation, options = _help_invocation(command)
        helps.setdefault(tuple(invocation), []).append((command, options))
    runs = {invocation: subprocess.Popen(invocation, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                         text=True) for invocation in helps}  # all at once: most of it is imports
    for invocation, process in runs.items():
        output, _ = process.communicate(timeout=300)
        for command, options in helps[invocation]:
            assert process.returncode == 0, f"{command}:\n{output[-2000:]}"
            unknown = [option for option in options if option not in output]
            assert not unknown, f"{command}: its help names no {', '.join(unknown)}"


def _layering() -> dict[str, set[str]]:
    """docs/architecture.md's table under "Who may import whom": package -> the packages it may import."""
    section = (ROOT / "docs" / "architecture.md").read_text().split("\n## Who may import whom\n", 1)[1]
    section = section.split("\n## ", 1)[0]
    allowed = {}
    for row in re.findall(r"^\| `(msfsu_\w+)` \| (.+) \|$", section, re.M):
        allowed[row[0]] = set(re.findall(r"`(msfsu_\w+)`", row[1]))
    return allowed


def _imports(package: str) -> dict[str, str]:
    """The workspace packages `package`'s code imports (lazy imports included), each with a file that does."""
    found = {}
    for path in sorted((ROOT / package / package).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([alias.name for alias in node.names] if isinstance(node, ast.Import) else
                     [node.module] if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 else [])
            for name in names:
                top = name.split(".")[0]
                if top.startswith("msfsu_") and top != package:
                    found.setdefault(top, path.relative_to(ROOT).as_posix())
    return found


def test_no_package_imports_one_its_row_in_the_architecture_page_does_not_name():
    allowed = _layering()
    packages = sorted(path.parent.name for path in ROOT.glob("msfsu_*/setup.py"))
    assert sorted(allowed) == packages
    wrong = [f"{package} imports {used} ({where})" for package in packages
             for used, where in _imports(package).items() if used not in allowed[package]]
    assert wrong == []
