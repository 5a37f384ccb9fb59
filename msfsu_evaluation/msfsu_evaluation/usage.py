"""The usage error shared by the evaluation commands (msfsu-eval-bag, msfsu-benchmark, msfsu-bag-video): exit code 2,
and the `--remap /bag/topic:=/target` option they share."""

from __future__ import annotations

from collections.abc import Collection, Sequence


class UsageError(ValueError):
    """The command line names something that cannot work; the message says what to change."""


def parse_remap_pairs(items: Sequence[str], bag_topics: Collection[str], targets: Sequence[str], target_role: str,
                 example_target: str) -> list[tuple[str, str]]:
    """`--remap /bag/topic:=/target` options -> [(bag topic, target)], in the order given.

    UsageError for a malformed item, a target that is not one of `targets` (the message calls it
    `target_role`), a source the bag does not hold, or a target fed twice.
    """
    pairs: list[tuple[str, str]] = []
    for item in items:
        source, separator, target = item.partition(":=")
        if not separator or not source.startswith("/") or not target.startswith("/"):
            raise UsageError(f"--remap '{item}' must look like /bag/topic:={example_target}")
        if target not in targets:
            raise UsageError(f"--remap target {target} is not {target_role} ({', '.join(targets)})")
        if source not in bag_topics:
            raise UsageError(f"--remap source {source} is not in the bag (topics: {', '.join(sorted(bag_topics))})")
        if any(target == fed for _, fed in pairs):
            raise UsageError(f"two --remap options feed {target}")
        pairs.append((source, target))
    return pairs
