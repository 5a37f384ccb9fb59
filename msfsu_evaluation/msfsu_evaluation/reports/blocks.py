"""`msfsu-results-blocks`: write the measured figures of the README and of docs/ from the committed result records
(never typed by hand).

    msfsu-results-blocks           # rewrite the marked blocks of every page
    msfsu-results-blocks --check   # exit 1 if a page differs from the records (a test runs this)
    msfsu-results-blocks --list    # the pages that hold a block, one a line (what to commit with them)

A block is `<!-- results:NAME -->` ... `<!-- /results:NAME -->`, on any of the hand-written pages (`pages()`:
README.md, docs/*.md, docs/results/README.md), wherever its topic is; NAME picks its generator
(reports.generators.GENERATORS), which reads the committed record into its type and renders it with that type's
renderer. Each generator's block stands on exactly one page. Generators write links relative to the repository's
root; a block's links are rewritten relative to the page it stands on.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path

from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT
from msfsu_evaluation.reports.generators import GENERATORS

PROG = "msfsu-results-blocks"
README = ROOT / "README.md"


def pages(root: Path = ROOT) -> list[Path]:
    """The hand-written pages: README.md, docs/*.md and docs/results/README.md (the rest of docs/results/ is written
    by its own commands)."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md")), root / "docs" / "results" / "README.md"]


BLOCK = re.compile(r"(<!-- results:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(<!-- /results:(?P=name) -->)", re.S)


_LINK_TARGET = re.compile(r"(\]\()([^)\s#]+)")


def relocate(body: str, page: Path) -> str:
    """`body`'s relative link targets, written from the repository's root, as seen from `page`."""
    def rewrite(match: re.Match) -> str:
        target = match.group(2)
        if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("/"):
            return match.group(0)
        return match.group(1) + Path(os.path.relpath(ROOT / target, page.parent)).as_posix()

    return _LINK_TARGET.sub(rewrite, body)


def render(text: str, page: Path = README) -> str:
    """`text` of `page` with every block rewritten from its generator."""
    def replace(match: re.Match) -> str:
        name = match.group("name")
        if name not in GENERATORS:
            raise KeyError(f"{page.name}: block '{name}' has no generator (known: {', '.join(GENERATORS)})")
        return f"{match.group(1)}{relocate(GENERATORS[name](), page)}\n{match.group(4)}"

    return BLOCK.sub(replace, text)


def placement(texts: dict[Path, str]) -> list[str]:
    """Problems with where the blocks stand: a generator whose block is on no page or on more than one."""
    where: dict[str, list[str]] = {name: [] for name in GENERATORS}
    for page, text in texts.items():
        for match in BLOCK.finditer(text):
            where.setdefault(match.group("name"), []).append(page.relative_to(ROOT).as_posix())
    problems = [f"block '{name}' is on no page: place it with its topic or remove its generator"
                for name, found in where.items() if not found]
    problems += [f"block '{name}' stands on {len(found)} pages ({', '.join(found)}): keep one"
                 for name, found in where.items() if len(found) > 1]
    return problems


def rewrite_page(page: Path, render_page: Callable[[str], str], command: str, description: str,
                 argv: list[str] | None = None) -> int:
    """The command line of `command`, which writes the generated blocks of `page`: rewrite them, or with --check
    compare only and exit 1 when the page is stale (`render_page`: the page's text -> its text as it should be)."""
    parser = argparse.ArgumentParser(prog=command, description=description)
    parser.add_argument("--check", action="store_true", help=f"compare only; exit 1 when {page.name} is stale")
    args = parser.parse_args(argv)
    try:
        text = page.read_text()
        updated = render_page(text)
    except (OSError, ValueError) as error:  # no page, or a page without its block: one line, no traceback
        print(f"{command}: {error}", file=sys.stderr)
        return 1
    if args.check:
        if updated != text:
            print(f"{page.relative_to(ROOT)} is stale: run {command}", file=sys.stderr)
            return 1
        return 0
    page.write_text(updated)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare only; exit 1 when a page is stale")
    parser.add_argument("--list", action="store_true", help="print the pages that hold a block, one a line")
    args = parser.parse_args(argv)
    texts = {page: page.read_text() for page in pages() if page.exists()}
    if args.list:
        print("\n".join(str(page.relative_to(ROOT)) for page, text in texts.items() if "<!-- results:" in text))
        return 0
    problems = placement(texts)
    for page, text in texts.items():
        updated = render(text, page)
        if updated == text:
            continue
        if args.check:
            problems.append(f"{page.relative_to(ROOT)} is stale: run {PROG}")
        else:
            page.write_text(updated)
    for problem in problems:
        print(problem, file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
