"""The page of the lane diagnosis from its record (render) and its figures (plot)."""

from __future__ import annotations

import json
from pathlib import Path


def render(study: dict) -> str:
    return "```\n" + json.dumps(study, indent=1)[:2000] + "\n```\n"


def plot(study: dict, out: Path) -> list[str]:
    return []
