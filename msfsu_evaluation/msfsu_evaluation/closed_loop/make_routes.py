"""Generate the committed route file from the towns' maps (run once; bump ROUTES_VERSION on change):

    python -m msfsu_evaluation.closed_loop.make_routes [--out PATH]

Needs MetaDrive without rendering (~3 s per town).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from msfsu_evaluation.closed_loop.suites import ROUTES_FILE, Candidate, build_route_file
from msfsu_sim.route_catalog import town_routes
from msfsu_sim.scenarios import HELDOUT_TOWNS, HELDOUT_WEATHERS, TOWNS, TRAIN_TOWNS, TRAIN_WEATHERS

COMMAND = "python -m msfsu_evaluation.closed_loop.make_routes"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=COMMAND, description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROUTES_FILE)
    options = parser.parse_args(argv)
    candidates = {town: [Candidate(route.checkpoints[:2], route.checkpoints[-1], route.junctions, route.length_m,
                                   route.start_road_m) for route in town_routes(town)] for town in TOWNS}
    conditions = {"train": (list(TRAIN_TOWNS), list(TRAIN_WEATHERS)),
                  "heldout": (list(HELDOUT_TOWNS), list(HELDOUT_WEATHERS))}
    data = build_route_file(candidates, conditions, COMMAND)
    routes = data.pop("routes")
    lines = ",\n  ".join(json.dumps(route) for route in routes)  # one route per line: readable diffs
    options.out.write_text(json.dumps(data)[:-1] + f', "routes": [\n  {lines}\n]}}\n')
    print(f"{len(routes)} routes -> {options.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
