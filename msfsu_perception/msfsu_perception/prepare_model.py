"""Build ahead of time what the perception node builds when it configures: the derived inference files of a checkpoint.

    python3 -m msfsu_perception.prepare_model CHECKPOINT [--backend auto] [--precision auto]

It loads the checkpoint exactly as the node's configure does (`perception_node.load_network`: compile on the backend
and precision asked, one warm-up inference), which writes into `<checkpoint>.deploy/` what a later load reads instead
of building it again (msfsu_perception.deploy_files): the ONNX export, the int8 model quantised from the checkpoint's
calibration frames (NNCF, tens of seconds on 2 cores, with torchvision's and NNCF's messages), OpenVINO's compile cache.
The Docker image runs it during `docker build` for the shipped default model, so that a container's perception node
configures in seconds (docs/deployment_docker.md). A checkpoint or backend that cannot be used: one line, exit code 1.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from msfsu_common.node_runner import StartupError
from msfsu_perception.deploy_files import DeployFiles
from msfsu_perception.perception_node import PerceptionStartup, load_network

PROGRAM = "python3 -m msfsu_perception.prepare_model"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROGRAM, description=__doc__.split("\n")[0])
    parser.add_argument("checkpoint", type=Path, help="MSFSU checkpoint (.pt)")
    parser.add_argument("--backend", default=PerceptionStartup.backend, help="as the node's backend parameter")
    parser.add_argument("--precision", default=PerceptionStartup.precision, help="as the node's precision parameter")
    options = parser.parse_args(argv)
    startup = PerceptionStartup(checkpoint=str(options.checkpoint), backend=options.backend,
                                precision=options.precision, device="cpu")
    started = time.perf_counter()
    try:
        model, warm_up_ms = load_network(startup)
    except StartupError as error:
        print(f"prepare_model: {error}", file=sys.stderr)
        return 1
    deploy = DeployFiles(options.checkpoint).directory
    print(f"{options.checkpoint}: {model.backend} {model.precision} built in {time.perf_counter() - started:.1f} s "
          f"(warm-up inference {warm_up_ms:.0f} ms); its derived files are in {deploy}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
