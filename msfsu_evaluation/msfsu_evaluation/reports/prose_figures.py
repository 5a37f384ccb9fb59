"""Figures in the hand-written prose of the README and docs/, each registered as a setting or sourced.

The hand-written pages are README.md, docs/*.md and docs/results/README.md (`reports.blocks.pages`; the rest of
docs/results/ is written by commands).

Measured numbers belong in generated blocks (`<!-- results:NAME -->`, msfsu-results-blocks) or pages a
command writes; prose that types one goes stale when the records change. A `<!-- generated:NAME -->` block is
written from the code (msfsu-node-parameters: the nodes' parameters) and is no prose either. This lists every
figure left in the prose (a number with a unit, a percentage, a ratio, a fraction such as 24/25) outside generated
blocks, code blocks and inline code, and checks it against `docs/prose_figures.tsv`, where each is registered once
per file as one of:

- `setting`: a parameter, budget, definition, or a number of the paper or of a standard: no record can
  contradict it (the note says what it is);
- `measured`: a figure measured by this project; the note names a committed file that holds the same number
  (checked: the number must appear in that file).

    msfsu-prose-figures            # check (exit 1 with a line per problem)
    msfsu-prose-figures --missing  # TSV lines for the figures not registered yet, to classify
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT
from msfsu_evaluation.reports.blocks import pages

REGISTRY = ROOT / "docs" / "prose_figures.tsv"
KINDS = ("setting", "measured")

_BLOCK = re.compile(r"<!-- (results|generated):([\w-]+) -->.*?<!-- /\1:\2 -->", re.S)
_FENCE = re.compile(r"```.*?```", re.S)
_INLINE_CODE = re.compile(r"`[^`\n]*`")
_LINK_TARGET = re.compile(r"\]\([^)\s]*\)")
_UNITS = (r"%|x\b|ms\b|s\b|min\b|h\b|Hz\b|km/h\b|km\b|m/s\b|m\b|GB\b|MB\b|kB\b|steps/s\b|frames/s\b|episodes/h\b|"
          r"samples/s\b|points?\b|frames?\b|episodes?\b|routes?\b|epochs?\b")
_NUMBER = r"\d+(?:,\d{3})*(?:\.\d+)?"
FIGURE = re.compile(rf"(?<![\w.,/])(?:{_NUMBER}(?:k\b)?(?: ?(?:{_UNITS})|(?=x\b))|\d+/\d+(?![\w/]))")


@dataclass(frozen=True)
class Figure:
    file: str
    line: int
    text: str
    context: str


def _blank(match: re.Match) -> str:
    """The match replaced by as many newlines (line numbers stay) or spaces."""
    return "".join("\n" if char == "\n" else " " for char in match.group(0))


def figures(file: str, text: str) -> list[Figure]:
    for pattern in (_BLOCK, _FENCE, _INLINE_CODE, _LINK_TARGET):
        text = pattern.sub(_blank, text)
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        for match in FIGURE.finditer(line):
            context = " ".join(line[max(0, match.start() - 60): match.end() + 25].split())
            found.append(Figure(file, number, match.group(0), context))
    return found


def load_registry(path: Path = REGISTRY) -> dict[tuple[str, str], tuple[str, str]]:
    """(file, figure) -> (kind, note)."""
    registry = {}
    with path.open(newline="") as handle:
        for row in csv.reader(handle, delimiter="\t"):
            if not row or row[0].startswith("#"):
                continue
            file, figure, kind, note = (row + ["", "", "", ""])[:4]
            registry[(file, figure)] = (kind, note)
    return registry


def prose_pages(root: Path = ROOT) -> list[str]:
    """The hand-written pages under `root`, relative to it (as the registry names them)."""
    return [page.relative_to(root).as_posix() for page in pages(root) if page.exists()]


def _number_in(number: str, path: Path) -> bool:
    text = path.read_text(errors="replace").replace(",", "")
    return re.search(rf"(?<![\d.]){re.escape(number.replace(',', ''))}(?![\d])", text) is not None


def problems(root: Path = ROOT, registry_path: Path = REGISTRY) -> list[str]:
    registry = load_registry(registry_path)
    found: dict[tuple[str, str], Figure] = {}
    for file in prose_pages(root):
        for figure in figures(file, (root / file).read_text()):
            found.setdefault((figure.file, figure.text), figure)
    issues = []
    for key, figure in found.items():
        if key not in registry:
            issues.append(f"{figure.file}:{figure.line}: figure '{figure.text}' in prose is not registered "
                          f"(generate it into a results block, remove it, or register it in {REGISTRY.name}): "
                          f"...{figure.context}...")
    for (file, text), (kind, note) in registry.items():
        if (file, text) not in found:
            issues.append(f"{registry_path.name}: '{text}' is registered for {file} but no longer there: remove the row")
        elif kind not in KINDS:
            issues.append(f"{registry_path.name}: '{text}' ({file}): kind '{kind}' is not one of {', '.join(KINDS)}")
        elif not note.strip():
            issues.append(f"{registry_path.name}: '{text}' ({file}): say what it is (setting) or where it is recorded")
        elif kind == "measured":
            source = root / note.split()[0]
            number = re.match(_NUMBER, text)
            if not source.is_file():
                issues.append(f"{registry_path.name}: '{text}' ({file}): source {note.split()[0]} is not a file")
            elif number is None or not _number_in(number.group(0), source):
                issues.append(f"{registry_path.name}: '{text}' ({file}): {note.split()[0]} does not hold that number")
    return issues


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="msfsu-prose-figures", description=__doc__.split("\n")[0])
    parser.add_argument("--missing", action="store_true", help="print TSV rows for unregistered figures")
    options = parser.parse_args(argv)
    if options.missing:
        registry = load_registry() if REGISTRY.exists() else {}
        seen = set()
        for file in prose_pages():
            for figure in figures(file, (ROOT / file).read_text()):
                key = (figure.file, figure.text)
                if key not in registry and key not in seen:
                    seen.add(key)
                    print(f"{figure.file}\t{figure.text}\t?\t{figure.line}: {figure.context}")
        return 0
    issues = problems()
    for issue in issues:
        print(issue, file=sys.stderr)
    return 1 if issues else 0


if __name__ == "__main__":
    sys.exit(main())
