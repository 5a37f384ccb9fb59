"""`msfsu-gate`: the accuracy gate of one checkpoint, from its calibration frames to the verdicts the node reads.

    msfsu-gate models/msfsu_default.pt --bags 'data/gate/test/*'                    # verdicts only
    msfsu-gate runs/cpu/best.pt --bags 'data/gate/test/*' --calibration-bags 'data/sim/train/*' \
        --val-bags 'data/sim/validation/*' --recipe-out benchmarks/int8_recipes/cpu --out gate.md

Steps, in this order, each only when its bags are given:
1. calibration frames (`--calibration-bags`, their training split; msfsu_perception.calibration): written when
   `<checkpoint>.calibration.npz` is missing or older than the checkpoint;
2. the int8 recipe (`--val-bags`; deploy.recipe, as `msfsu-int8-recipe` runs it): the
   per-layer ranking of `--recipe-out`'s JSON is reused when it measured this checkpoint's content in this deploy
   format, and msfsu-int8-recipe refuses it for other calibration or validation frames;
3. scoring (`--bags`, the held-out gate bags; deploy.scoring): every fast path of the device
   against torch fp32 on the CPU, the frames of all bags pooled; the verdicts go to the checkpoint's gate record
   (msfsu_perception.gate_verdicts, laid out by deploy_files), which precision "auto" reads.

This command is the one writer of gate verdicts: the perception and GPU benchmarks run it (their --record-gate)
instead of recording verdicts themselves, and read back what it scored (the gate record, or `--json` with
`--no-record`). Step 1's freshness rule (`ensure_calibration`) is the only one: calibration frames are kept while they
are newer than the checkpoint.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msfsu_perception.gate_verdicts import GateResult

PROG = "msfsu-gate"
CPU_BACKENDS = ("onnxruntime", "openvino")  # the fast paths on the CPU; torch fp32 is the reference
GPU_PRECISIONS = ("fp32", "fp16", "bf16")  # torch on a CUDA device (backends.cuda_graph_runner)


def candidates(device: str) -> list[tuple[str, str]]:
    """The (backend, precision) paths the gate scores on `device`: every installed precision of ONNX Runtime and
    OpenVINO on the CPU, torch's GPU precisions on a CUDA device."""
    from msfsu_perception.backends import SUPPORTED_PRECISIONS, is_installed

    if device == "cpu":
        return [(backend, precision) for backend in CPU_BACKENDS if is_installed(backend)
                for precision in SUPPORTED_PRECISIONS[backend]]
    return [("torch", precision) for precision in GPU_PRECISIONS]


def ensure_calibration(checkpoint: Path, bags: Sequence[str], cache_dir: Path, frames: int) -> str:
    """Step 1: calibration frames from the training split of `bags` unless current ones exist; what was done."""
    from msfsu_perception import calibration

    if calibration.is_current(checkpoint):
        return f"calibration frames kept: {calibration.calibration_path(checkpoint)} is newer than {checkpoint}"
    return f"wrote {calibration.summary(calibration.calibrate(checkpoint, bags, cache_dir, frames))}"


def reusable_ranking(record: Path, checkpoint: Path) -> bool:
    """A sensitivity record measured this checkpoint's content on the exported graph of this deploy format."""
    from msfsu_perception.deploy_files import DEPLOY_FORMAT_VERSION, file_digest

    if not record.is_file():
        return False
    stored = json.loads(record.read_text())
    return (stored.get("deploy_format"), stored.get("checkpoint_digest")) == (DEPLOY_FORMAT_VERSION,
                                                                             file_digest(checkpoint))


def recipe_argv(checkpoint: Path, val_bags: Sequence[str], frames: int, out: Path | None, threads: int,
                cache_dir: Path) -> list[str]:
    """The `msfsu-int8-recipe` arguments of step 2; options at that command's defaults are left out (the recipe
    records its command)."""
    from msfsu_evaluation.deploy import recipe

    defaults = recipe.parse_args([str(checkpoint), "--val-bags", "-"])
    argv = [str(checkpoint), "--val-bags", *val_bags, "--frames", str(frames)]
    if threads != defaults.threads:
        argv += ["--threads", str(threads)]
    if cache_dir != defaults.cache_dir:
        argv += ["--cache-dir", str(cache_dir)]
    if out is not None and reusable_ranking(out.with_suffix(".json"), checkpoint):
        argv += ["--ranking-from", str(out.with_suffix(".json"))]
    return argv + (["--out", str(out)] if out is not None else [])


@dataclass(frozen=True)
class GateRun:
    """What step 3 scored and where its verdicts went."""

    results: list[GateResult]
    held_out: dict[str, Any]  # scoring.describe_held_out of the pooled frames
    recorded: Path | None  # the gate record, None when not recorded


def score(checkpoint: Path, bags: Sequence[str | Path], cache_dir: Path, *, device: str = "cpu",
          frames_per_bag: int | None = None, threads: int | None = None, record: bool = True,
          command: str | None = None) -> GateRun:
    """Step 3: every path of candidates(device) against torch fp32 on the pooled frames of `bags` (paths or globs);
    with `record`, the verdicts (and `command`, how to run the gate again) go to the checkpoint's gate record."""
    from msfsu_evaluation.deploy.scoring import run_gate
    from msfsu_perception.bag_paths import expand_bag_paths
    from msfsu_perception.gate_verdicts import record_gate_results

    paths = expand_bag_paths([str(bag) for bag in bags])
    results, held_out = run_gate(checkpoint, paths, candidates(device), cache_dir, frames_per_bag, threads,
                                 device=device)
    recorded = record_gate_results(checkpoint, results, held_out, command, device=device) if record else None
    return GateRun(results, held_out, recorded)


def report_lines(checkpoint: Path, run: GateRun) -> list[str]:
    """The verdicts as markdown (gate_report.gate_lines) and where they were recorded."""
    from msfsu_evaluation.deploy.gate_report import gate_lines

    lines = gate_lines(checkpoint, run.results, run.held_out)
    return lines + (["", f"recorded in {run.recorded}"] if run.recorded is not None else [])


def gate_argv(checkpoint: Path, bags: Sequence[str], *, device: str = "cpu", threads: int | None = None,
              frames_per_bag: int | None = None) -> list[str]:
    """The command line that scores `checkpoint` on `bags`, options at their defaults left out (the command is
    recorded with the verdicts)."""
    argv = [str(checkpoint), "--bags", *bags]
    if device != "cpu":
        argv += ["--device", device]
    if threads is not None and threads != parse_args(argv).threads:
        argv += ["--threads", str(threads)]
    return argv + (["--frames-per-bag", str(frames_per_bag)] if frames_per_bag else [])


def run_gate(argv: Sequence[str], record: bool, scored: Path) -> tuple[list[str], GateRun]:
    """This command with `argv`, as the benchmarks run it (their --record-gate): with `record` it stores the verdicts
    in the checkpoint's gate record, exactly as run alone; else it only scores them, into `scored` (--json). Its
    page's lines and what it scored, read back from what it wrote."""
    import contextlib
    import io

    from msfsu_perception.deploy_files import DeployFiles
    from msfsu_perception.gate_verdicts import gate_record, results_from_record

    extra = [] if record else ["--no-record", "--json", str(scored)]
    with contextlib.redirect_stdout(io.StringIO()):
        status = main([*argv, *extra])
    if status != 0:
        raise SystemExit(f"{PROG} {shlex.join(argv)} exited with {status}")
    args = parse_args(argv)
    stored = gate_record(args.checkpoint, args.device) if record else json.loads(scored.read_text())
    run = GateRun(results_from_record(stored), stored["held_out"],
                  DeployFiles(args.checkpoint).gate_record_of(args.device) if record else None)
    return [f"Made by `{stored['command']}`", "", *report_lines(args.checkpoint, run)], run


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    from msfsu_evaluation.deploy.recipe import DEFAULT_FRAMES as RECIPE_FRAMES
    from msfsu_perception.calibration import DEFAULT_FRAMES as CALIBRATION_FRAMES

    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.splitlines()[1:]))
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--bags", nargs="+", required=True,
                        help="held-out bags/globs with class ids whose pooled frames decide (scripts/gate_bags.sh)")
    parser.add_argument("--calibration-bags", nargs="+", default=[],
                        help="bags/globs whose 'train' split gives the int8 calibration frames")
    parser.add_argument("--calibration-frames", type=int, default=CALIBRATION_FRAMES)
    parser.add_argument("--val-bags", nargs="+", default=[],
                        help="bags/globs (validation split, never the gate's) to choose the int8 recipe on")
    parser.add_argument("--recipe-frames", type=int, default=RECIPE_FRAMES,
                        help="validation frames of the recipe search, spread over the bags (0: every frame)")
    parser.add_argument("--recipe-out", type=Path,
                        help="the sensitivity record as <out>.md and <out>.json (its ranking is reused next time)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="where the scored paths run")
    parser.add_argument("--frames-per-bag", type=int, help="at most this many frames per gate bag, evenly spaced")
    parser.add_argument("--threads", type=int, default=2, help="intra-op threads")
    parser.add_argument("--cache-dir", type=Path, default=Path("data/cache"), help="decoded frame cache")
    parser.add_argument("--no-record", action="store_true", help="score only: leave the gate record as it is")
    parser.add_argument("--out", type=Path, help="also write the verdicts as markdown here")
    parser.add_argument("--json", type=Path,
                        help="also write this run's verdicts as a gate record here (what a caller reads that does not "
                             "record them: --no-record)")
    args = parser.parse_args(argv)
    if not args.checkpoint.is_file():
        raise SystemExit(f"{PROG}: no checkpoint {args.checkpoint}")
    if args.val_bags and args.device != "cpu":
        raise SystemExit(f"{PROG}: --val-bags chooses the CPU's int8 recipe: run it with --device cpu")
    return args


def run(args: argparse.Namespace, command: str) -> int:
    """The three steps of the module docstring; returns the exit status."""
    from msfsu_evaluation.deploy import recipe

    if args.calibration_bags:
        print(ensure_calibration(args.checkpoint, args.calibration_bags, args.cache_dir, args.calibration_frames),
              flush=True)
    if args.val_bags:
        status = recipe.main(recipe_argv(args.checkpoint, args.val_bags, args.recipe_frames, args.recipe_out,
                                         args.threads, args.cache_dir))
        if status != 0:
            return status
    gate_run = score(args.checkpoint, args.bags, args.cache_dir, device=args.device,
                     frames_per_bag=args.frames_per_bag, threads=args.threads, record=not args.no_record,
                     command=command)
    text = "\n".join([f"Made by `{command}`", "", *report_lines(args.checkpoint, gate_run)]) + "\n"
    print(text, end="")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    if args.json is not None:
        from msfsu_perception.gate_verdicts import run_record

        args.json.parent.mkdir(parents=True, exist_ok=True)
        record = run_record(args.checkpoint, gate_run.results, gate_run.held_out, command)
        args.json.write_text(json.dumps(record, indent=1) + "\n")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    from msfsu_common.bag_io import BagError
    from msfsu_perception.backends import BackendUnavailableError
    from msfsu_perception.checkpoint import CheckpointError
    from msfsu_perception.frame_cache import CacheSpaceError
    from msfsu_perception.int8_recipe import RecipeError

    args = parse_args(argv)
    command = f"{PROG} " + shlex.join(sys.argv[1:] if argv is None else list(argv))
    try:
        return run(args, command)
    except (CheckpointError, BagError, CacheSpaceError, RecipeError, BackendUnavailableError, ValueError) as error:
        print(f"{PROG}: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
