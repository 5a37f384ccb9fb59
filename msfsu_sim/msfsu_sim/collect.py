"""`msfsu-collect`: driving episodes -> one rosbag2 MCAP bag per episode (paper III-A), labelled by the expert.

The command line of a collection: the plan (`collection_plan`: episodes, seeds, resume), the routes
(`collection_routes`), who drives (`episode_driver`: the expert, or on-policy rounds, DAgger, with `--driver
CHECKPOINT --beta B`), the recording of an episode and which episodes are kept (`episode_recording`) and the
worker pool (`collection_workers`). Dropped episodes are listed in `dropped.jsonl`; a re-run of the same command
resumes.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from msfsu_common import bag_io
from msfsu_common.processes import interrupt_on_signals
from msfsu_sim.collection_plan import UsageError, check_resume, default_scenarios, pending, plan
from msfsu_sim.collection_workers import collect
from msfsu_sim.episode_driver import EXPERT, Driver, driver_network, keep_network, load_network
from msfsu_sim.episode_recording import EpisodeResult
from msfsu_sim.scenarios import TOWNS, TRAFFIC, WEATHERS


def summary(results: Sequence[EpisodeResult]) -> str:
    """Per traffic level: kept episodes, frames, frames labelled below SLOW_MPS (stopping), network-driven."""
    lines = ["traffic | kept episodes | frames | label < 1 m/s | driven by the network"]
    for level in sorted({r.episode.traffic for r in results}, key=list(TRAFFIC).index):
        mine = [r for r in results if r.episode.traffic == level]
        frames = sum(r.frames for r in mine)

        def share(count: int) -> str:
            return f"{count} ({100 * count / frames:.1f} %)" if frames else "0"

        lines.append(f"{level} | {sum(r.kept for r in mine)}/{len(mine)} | {frames} | "
                     f"{share(sum(r.slow_frames for r in mine))} | {share(sum(r.network_frames for r in mine))}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="msfsu-collect", description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, required=True, help="dataset root; bags go to <output>/<split>/")
    parser.add_argument("--split", choices=bag_io.SPLITS, required=True)
    parser.add_argument("--episodes", type=int, default=1, help="episodes per town x weather x traffic")
    parser.add_argument("--towns", nargs="+", choices=list(TOWNS), metavar="TOWN",
                        help="default: training towns (test: held-out towns)")
    parser.add_argument("--weathers", nargs="+", choices=list(WEATHERS), metavar="WEATHER",
                        help="default: training weathers (test: held-out weathers)")
    parser.add_argument("--traffic", nargs="+", choices=list(TRAFFIC), default=["empty", "regular", "dense"])
    parser.add_argument("--max-steps", type=int, default=3000, help="episode length limit (10 steps = 1 s)")
    parser.add_argument("--record-from", type=int, default=0, metavar="STEP",
                        help="drive the first STEP steps without recording them (the bag starts at step STEP)")
    parser.add_argument("--seed", type=int, default=0, help="base seed (episode seeds derive from it)")
    parser.add_argument("--workers", type=int, default=1, help="parallel simulator processes")
    parser.add_argument("--no-noise", action="store_true", help="disable steering-noise injection")
    parser.add_argument("--full-meshes", action="store_true",
                        help="draw traffic with MetaDrive's full models instead of the light meshes (to compare)")
    parser.add_argument("--driver", type=Path, metavar="CHECKPOINT",
                        help="on-policy round (DAgger): this network drives the steps the expert does not "
                             "(default: the expert drives every step)")
    parser.add_argument("--beta", type=float,
                        help="probability that the expert drives a step (default 0 with --driver, else 1)")
    parser.add_argument("--round", type=int, default=0,
                        help="collection round: 0 expert data; on-policy rounds 1, 2, ... (own bag names and seeds)")
    parser.add_argument("--backend", default="auto", choices=["auto", "torch", "onnxruntime", "openvino"],
                        help="the driver network's backend, as the perception node's parameter")
    parser.add_argument("--precision", default="auto", choices=["auto", "fp32", "bf16", "int8"],
                        help="the driver network's precision, as the perception node's parameter")
    return parser


def driver_from_options(options: argparse.Namespace) -> Driver:
    """The episode driver the options ask for (UsageError if they cannot work)."""
    beta = options.beta if options.beta is not None else (0.0 if options.driver else 1.0)
    if not 0.0 <= beta <= 1.0:
        raise UsageError(f"--beta {beta} is not a probability in [0, 1]")
    if options.round < 0 or options.episodes < 1 or options.max_steps < 1 or options.workers < 1:
        raise UsageError("--round must be >= 0 and --episodes, --max-steps, --workers >= 1")
    if not 0 <= options.record_from < options.max_steps:
        raise UsageError(f"--record-from {options.record_from} must be in [0, --max-steps {options.max_steps})")
    if options.driver is None:
        if beta < 1.0:
            raise UsageError(f"--beta {beta} lets a network drive: name it with --driver CHECKPOINT")
        return EXPERT
    if options.round < 1:
        raise UsageError("--driver collects an on-policy round: give it --round N (N >= 1), so its bags sit "
                         "beside the expert's round 0 instead of being taken for them")
    from msfsu_perception.checkpoint import CheckpointError
    from msfsu_perception.deploy_files import file_digest
    from msfsu_perception.inference import BackendUnavailableError

    driver = Driver(str(options.driver), beta, "", options.backend, options.precision)
    try:  # load it once here: a bad checkpoint is refused before any simulator starts
        network = load_network(driver)
    except (CheckpointError, BackendUnavailableError, ValueError, OSError) as error:
        raise UsageError(f"cannot drive with {options.driver}: {str(error).splitlines()[0]}") from None
    driver = Driver(driver.checkpoint, beta, file_digest(options.driver), options.backend, options.precision)
    keep_network(driver, network)  # the in-process worker (--workers 1) uses it
    return driver


def main(argv: list[str] | None = None) -> int:
    options = build_parser().parse_args(argv)
    from tqdm import tqdm

    default_towns, default_weathers = default_scenarios(options.split)
    planned = plan(options.split, options.towns or default_towns, options.weathers or default_weathers,
                   options.traffic, options.episodes, options.seed, options.round)
    try:
        driver = driver_from_options(options)
        check_resume(options.output, planned, driver)
    except UsageError as error:
        print(f"msfsu-collect: {error}", file=sys.stderr)
        return 2
    interrupt_on_signals()  # SIGTERM, and SIGINT also in a background job (`kill -INT`): stop, keep what is done
    todo = len(pending(options.output, planned))
    who = "the expert"
    if driver.on_policy:
        network = driver_network(driver)
        who = (f"{driver.checkpoint} on {network.backend}/{network.precision} and the expert with probability "
               f"{driver.beta}")
    print(f"{len(planned)} episodes planned (round {options.round}, driven by {who}), {len(planned) - todo} "
          "already done", file=sys.stderr)
    results = []
    try:
        with tqdm(total=todo, unit="episode") as progress:
            for result in collect(options.output, planned, options.workers, options.max_steps, not options.no_noise,
                                  driver, options.record_from, not options.full_meshes):
                results.append(result)
                progress.set_postfix_str(f"{result.episode.name}: {result.reason}")
                progress.update()
    except KeyboardInterrupt:
        print("msfsu-collect: interrupted (re-run the same command to resume)", file=sys.stderr)
        return 1
    print(f"kept {sum(r.kept for r in results)}/{todo} new episodes in {options.output}", file=sys.stderr)
    if results:
        print(summary(results), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
