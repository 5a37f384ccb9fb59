"""Why a network crosses solid lines at its turns: open-loop experiments on recorded bags that can fail.

1. **Steer error per command branch**, on the same frames for every network and precision: each run of one command in
   a bag is split into its approach (the frames before the expert's steer first reaches half of the run's peak, in
   the turn's direction) and the turn itself. Per group: the mean absolute steer error and the signed error
   (network minus expert; steer is CARLA's, positive right, so a negative signed error on a LEFT approach is a car
   turning in early). Each network is also paired with a reference network on the same frames. Intervals are 95 %
   bootstrap intervals over command runs (the frames of one run are not independent; resampling runs keeps them
   together).
2. **Every branch on the turn approaches**: the same frames run through each command's branch, so a bias that only the
   turn's own branch has is the branch's (what it learned to do on that command), and one that every branch shares is
   the encoder's features.
3. **The scene loss's share of the encoder's gradient** at the trained weights, for the networks with a decoder:
   the gradient of the control loss (lambda1 L_steer + lambda2 L_speed) and of the scene loss (lambda3 L_scene) on
   the encoder's parameters, each summed over the same frames (all, and the LEFT frames alone), their norms' ratio
   and the cosine between them. The network is in eval mode (batch norm's running statistics, no dropout), so the
   numbers repeat.

    python -m msfsu_evaluation.lateral_study --bags 'data/v2/gate/test/*' \
        --network msfsu=models/msfsu_default.pt --network msf=models/msf.pt --reference msf --out DIR
    python -m msfsu_evaluation.lateral_study --render DIR   # the page again from DIR/lateral_study.json

A network is NAME=CHECKPOINT[:BACKEND/PRECISION] (default auto/auto: what the perception node runs on this machine).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_common.benchmark_run import BenchmarkRun
from msfsu_common.road_option import RoadOption
from msfsu_evaluation.deploy.scoring import HeldOutBag, describe_held_out, load_held_out, predict_held_out
from msfsu_evaluation.records.lateral_study import (PAGE_NAME, RECORD_NAME, BranchSteer, GradientShare, LateralStudy,
                                                   PairedSteer, SteerErrors)

ONSET_SHARE = 0.5  # a turn begins where the expert's steer first reaches this share of the run's peak
TURNS = (RoadOption.LEFT, RoadOption.RIGHT)
GROUP_ORDER = ("LEFT approach", "LEFT turn", "RIGHT approach", "RIGHT turn", "STRAIGHT", "LANE_FOLLOW", "all")
BOOTSTRAP_RESAMPLES = 2000


def command_runs(command: np.ndarray) -> list[tuple[int, int]]:
    """[(start, stop)] of each maximal run of one command value, in order."""
    if len(command) == 0:
        return []
    edges = np.flatnonzero(np.diff(command.astype(np.int64))) + 1
    starts = np.concatenate([[0], edges])
    stops = np.concatenate([edges, [len(command)]])
    return [(int(a), int(b)) for a, b in zip(starts, stops)]


def turn_onset(expert_steer: np.ndarray, option: RoadOption) -> int:
    """Index in a run of `option` where the turn begins: the first frame whose steer toward the turn (negative for
    LEFT) reaches ONSET_SHARE of the run's peak; len(run) when the expert never steers toward it."""
    toward = -expert_steer if option == RoadOption.LEFT else expert_steer
    peak = float(toward.max(initial=0.0))
    if peak <= 0.0:
        return len(expert_steer)
    return int(np.argmax(toward >= ONSET_SHARE * peak))


@dataclass(frozen=True)
class FrameGroups:
    """Each pooled frame's group and run (the bootstrap's cluster)."""

    group: np.ndarray  # (N,) object: a GROUP_ORDER name other than "all"
    cluster: np.ndarray  # (N,) int64: the command run the frame belongs to, unique over the bags

    @classmethod
    def of(cls, bags: Sequence[HeldOutBag]) -> FrameGroups:
        groups, clusters, next_cluster = [], [], 0
        for bag in bags:
            command, steer = bag.truth.command[bag.indices], bag.steer
            group = np.empty(len(bag), object)
            cluster = np.empty(len(bag), np.int64)
            for start, stop in command_runs(command):
                option = RoadOption(int(command[start]))
                cluster[start:stop] = next_cluster
                next_cluster += 1
                if option in TURNS:
                    onset = start + turn_onset(steer[start:stop], option)
                    group[start:onset] = f"{option.name} approach"
                    group[onset:stop] = f"{option.name} turn"
                else:
                    group[start:stop] = option.name
            groups.append(group)
            clusters.append(cluster)
        return cls(np.concatenate(groups), np.concatenate(clusters))

    def select(self, name: str) -> np.ndarray:
        return np.ones(len(self.group), bool) if name == "all" else self.group == name


def cluster_bootstrap(values: np.ndarray, clusters: np.ndarray, resamples: int = BOOTSTRAP_RESAMPLES,
                      seed: int = 0) -> tuple[float, float]:
    """95 % percentile interval of the mean of `values`, resampling whole clusters with replacement."""
    ids, inverse = np.unique(clusters, return_inverse=True)
    sums = np.bincount(inverse, weights=values, minlength=len(ids))
    counts = np.bincount(inverse, minlength=len(ids)).astype(np.float64)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(ids), (resamples, len(ids)))
    means = sums[draws].sum(axis=1) / counts[draws].sum(axis=1)
    low, high = np.percentile(means, [2.5, 97.5])
    return float(low), float(high)


BRANCH_GROUPS = ("LEFT approach", "RIGHT approach")


def branch_predictions(model: Any, bags: Sequence[HeldOutBag]) -> dict[str, np.ndarray]:
    """{RoadOption name: (N,) steer of that branch on every pooled frame}."""
    from msfsu_perception.deploy_files import cached_inputs

    preprocess = model.preprocess
    inputs = np.empty((preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32)
    steer = {option.name: [] for option in RoadOption}
    for bag in bags:
        truth = bag.truth
        for index in bag.indices:
            row = truth.rows[index]
            cached_inputs(truth.cache.rgb[row], None if truth.cache.depth is None else truth.cache.depth[row], inputs)
            for option in RoadOption:
                steer[option.name].append(model.predict(inputs, option).steer)
    return {name: np.asarray(values) for name, values in steer.items()}


def own_command_steer(per_branch: dict[str, np.ndarray], bags: Sequence[HeldOutBag]) -> np.ndarray:
    """(N,) the steer of each pooled frame's own command's branch, picked from `branch_predictions`."""
    commands = np.concatenate([bag.truth.command[bag.indices] for bag in bags])
    steer = np.empty(len(commands))
    for option in RoadOption:
        steer[commands == option.value] = per_branch[option.name][commands == option.value]
    return steer


def branch_steer(network: str, branches: dict[str, np.ndarray], expert: np.ndarray, groups: FrameGroups
                 ) -> list[BranchSteer]:
    rows = []
    for group in (g for g in BRANCH_GROUPS if groups.select(g).any()):
        mask = groups.select(group)
        for branch, steer in branches.items():
            error = steer[mask] - expert[mask]
            rows.append(BranchSteer(network, group, branch, int(mask.sum()), float(error.mean()),
                                    cluster_bootstrap(error, groups.cluster[mask])))
    return rows


def common_frames(loaded: dict[Any, list[HeldOutBag]]) -> dict[Any, list[HeldOutBag]]:
    """The same bags loaded for several preprocessings (a network without depth keeps frames whose depth is unusable)
    cut to the frames every one has, matched by stamp, so that every network is scored on the same frames."""
    first = next(iter(loaded.values()))
    common = [set(bag.truth.stamps_ns[bag.indices].tolist()) for bag in first]
    for bags in loaded.values():
        common = [c & set(bag.truth.stamps_ns[bag.indices].tolist()) for c, bag in zip(common, bags)]
    return {key: [HeldOutBag(bag.path, bag.truth, bag.indices[np.isin(bag.truth.stamps_ns[bag.indices],
                                                                        np.fromiter(c, np.int64, len(c)))])
                  for bag, c in zip(bags, common)]
            for key, bags in loaded.items()}


def _errors(network: str, runtime: str, name: str, error: np.ndarray, groups: FrameGroups,
            mask: np.ndarray) -> SteerErrors:
    clusters = groups.cluster[mask]
    return SteerErrors(network, runtime, name, int(mask.sum()), len(np.unique(clusters)),
                       float(np.abs(error[mask]).mean()), cluster_bootstrap(np.abs(error[mask]), clusters),
                       float(error[mask].mean()), cluster_bootstrap(error[mask], clusters))


def steer_errors(predictions: dict[str, np.ndarray], runtimes: dict[str, str], expert: np.ndarray,
                 groups: FrameGroups, reference: str | None) -> tuple[list[SteerErrors], list[PairedSteer]]:
    """Per network and group: its errors; per network other than `reference`: the paired differences."""
    rows, paired = [], []
    for name in (g for g in GROUP_ORDER if groups.select(g).any()):
        mask = groups.select(name)
        for network, steer in predictions.items():
            rows.append(_errors(network, runtimes[network], name, steer - expert, groups, mask))
        if reference is None:
            continue
        base = predictions[reference] - expert
        for network, steer in predictions.items():
            if network == reference:
                continue
            error = steer - expert
            mae = np.abs(error[mask]) - np.abs(base[mask])
            signed = error[mask] - base[mask]
            clusters = groups.cluster[mask]
            paired.append(PairedSteer(network, reference, name, int(mask.sum()), float(mae.mean()),
                                      cluster_bootstrap(mae, clusters), float(signed.mean()),
                                      cluster_bootstrap(signed, clusters)))
    return rows, paired


def gradient_share(checkpoint: Path, network: str, bags: Sequence[HeldOutBag], batch_size: int = 32
                   ) -> list[GradientShare]:
    """GradientShare on all frames and on the LEFT frames; [] for a network without a decoder."""
    import torch

    from msfsu_perception.checkpoint import load_checkpoint
    from msfsu_perception.deploy_files import cached_inputs
    from msfsu_perception.losses import LossConfig, scene_loss, weighted_steer_loss

    loaded = load_checkpoint(checkpoint)
    model, preprocess, config = loaded.model.eval(), loaded.preprocess, LossConfig()
    if not model.config.has_segmentation:
        return []
    parameters = [p for p in model.encoder.parameters() if p.requires_grad]
    frames = [(bag, int(index)) for bag in bags for index in bag.indices]
    commands = np.array([bag.truth.command[index] for bag, index in frames])
    shares = []
    for frames_of, keep in (("all", np.ones(len(frames), bool)), ("LEFT", commands == RoadOption.LEFT)):
        chosen = [frames[i] for i in np.flatnonzero(keep)]
        if not chosen:
            continue
        totals = {"control": [torch.zeros_like(p) for p in parameters],
                  "scene": [torch.zeros_like(p) for p in parameters]}
        for start in range(0, len(chosen), batch_size):
            batch = chosen[start:start + batch_size]
            inputs = np.empty((len(batch), preprocess.channels, preprocess.input_height, preprocess.input_width),
                              np.float32)
            for row, (bag, index) in enumerate(batch):
                cache_row = bag.truth.rows[index]
                depth = None if bag.truth.cache.depth is None else bag.truth.cache.depth[cache_row]
                cached_inputs(bag.truth.cache.rgb[cache_row], depth, inputs[row])
            command = torch.tensor([RoadOption(int(bag.truth.command[i])).branch_index for bag, i in batch])
            steer = torch.tensor([float(bag.truth.steer[i]) for bag, i in batch])
            speed = torch.tensor([float(bag.truth.target_speed[i]) / loaded.speed_scale for bag, i in batch])
            class_ids = torch.from_numpy(np.stack([bag.truth.class_ids(i) for bag, i in batch]).astype(np.int64))
            output = model(torch.from_numpy(inputs), command)
            # sums over frames: the batch means weighted by batch size, so every frame counts alike
            control = len(batch) * (config.steer_weight * weighted_steer_loss(
                output.steer, steer, config.alpha, config.beta, config.gamma)
                + config.speed_weight * torch.nn.functional.mse_loss(output.speed, speed))
            scene = len(batch) * config.scene_weight * scene_loss(output.segmentation_logits, class_ids)
            for name, loss in (("control", control), ("scene", scene)):
                grads = torch.autograd.grad(loss, parameters, retain_graph=name == "control")
                for total, grad in zip(totals[name], grads):
                    total.add_(grad)
        control_vector = torch.cat([g.flatten() for g in totals["control"]]).double()
        scene_vector = torch.cat([g.flatten() for g in totals["scene"]]).double()
        control_norm, scene_norm = float(control_vector.norm()), float(scene_vector.norm())
        cosine = float(control_vector @ scene_vector) / max(control_norm * scene_norm, 1e-30)
        shares.append(GradientShare(network, frames_of, len(chosen), control_norm, scene_norm,
                                    scene_norm / max(control_norm, 1e-30), cosine))
    return shares


def parse_network(text: str) -> tuple[str, Path, str, str]:
    """NAME=CHECKPOINT[:BACKEND/PRECISION] -> (name, checkpoint, backend, precision)."""
    name, separator, rest = text.partition("=")
    if not separator or not name or not rest:
        raise argparse.ArgumentTypeError(f"expected NAME=CHECKPOINT[:BACKEND/PRECISION], got '{text}'")
    checkpoint, _, runtime = rest.partition(":")
    backend, _, precision = (runtime or "auto/auto").partition("/")
    return name, Path(checkpoint), backend, precision or "auto"


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bags", nargs="+", help="bags/globs with expert actions and class ids (held-out ones, or a training town's validation bags)")
    parser.add_argument("--network", action="append", type=parse_network, default=[],
                        help="NAME=CHECKPOINT[:BACKEND/PRECISION] (repeat; default runtime auto/auto)")
    parser.add_argument("--reference", help="the network every other one is paired with")
    parser.add_argument("--branches", action="store_true", help="also every branch on the turn approaches")
    parser.add_argument("--gradients", action="store_true", help="also the scene loss's share of the gradient")
    parser.add_argument("--cache-dir", type=Path, default=Path("runs/cache"), help="frame cache of the bags")
    parser.add_argument("--threads", type=int, default=None, help="inference threads (default: the library's)")
    parser.add_argument("--out", type=Path, help="directory of lateral_study.json and its page")
    parser.add_argument("--render", type=Path, metavar="DIR", help="only rewrite DIR's page from its record")
    args = parser.parse_args(argv)
    if args.render is None and (not args.bags or not args.network or args.out is None):
        parser.error("--bags, --network and --out are needed (or --render DIR)")
    names = [name for name, *_ in args.network]
    if len(set(names)) != len(names):
        parser.error(f"network names repeat: {', '.join(names)}")
    if args.reference is not None and args.reference not in names:
        parser.error(f"--reference {args.reference} is not one of the networks ({', '.join(names)})")
    return args


def run(args: argparse.Namespace, argv: Sequence[str] | None) -> LateralStudy:
    from msfsu_perception.bag_topics import BagTopics
    from msfsu_perception.checkpoint import load_checkpoint
    from msfsu_perception.bag_paths import expand_bag_paths
    from msfsu_perception.inference import DrivingModel

    started = BenchmarkRun.start("python -m msfsu_evaluation.lateral_study", argv, quoted=True)
    bag_paths = expand_bag_paths(args.bags)
    preprocess_of = {name: load_checkpoint(checkpoint).preprocess for name, checkpoint, _, _ in args.network}
    frames_of = common_frames({p: load_held_out(bag_paths, BagTopics(), p, args.cache_dir)
                               for p in dict.fromkeys(preprocess_of.values())})
    bags = next(iter(frames_of.values()))
    groups = FrameGroups.of(bags)
    expert = np.concatenate([bag.steer for bag in bags])
    predictions, runtimes, networks = {}, {}, {}
    branches: list[BranchSteer] = []
    for name, checkpoint, backend, precision in args.network:
        model = DrivingModel.from_checkpoint(checkpoint, args.threads, backend, precision)
        runtimes[name] = f"{model.backend}/{model.precision}"
        networks[name] = {"checkpoint": checkpoint.as_posix(), "runtime": runtimes[name]}
        bags_of_network = frames_of[preprocess_of[name]]
        if args.branches:  # every branch on every frame: the frame's own command's answer is one of them
            per_branch = branch_predictions(model, bags_of_network)
            predictions[name] = own_command_steer(per_branch, bags_of_network)
            branches += branch_steer(name, per_branch, expert, groups)
        else:
            predictions[name] = np.concatenate([predict_held_out(model, bag).steer for bag in bags_of_network])
        print(f"{name}: {runtimes[name]}, {len(expert)} frames", file=sys.stderr)
    steer, paired = steer_errors(predictions, runtimes, expert, groups, args.reference)
    gradients = []
    if args.gradients:
        seen: set[Path] = set()
        for name, checkpoint, _, _ in args.network:
            if checkpoint.resolve() not in seen:
                seen.add(checkpoint.resolve())
                gradients += gradient_share(checkpoint, name, frames_of[preprocess_of[name]])
    started.end()
    return LateralStudy(asdict(started), describe_held_out(bags), networks, args.reference, ONSET_SHARE,
                        steer, paired, branches, gradients)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    if args.render is not None:
        record = args.render / RECORD_NAME
        if not record.exists():
            print(f"lateral_study: {record} does not exist", file=sys.stderr)
            return 2
        (args.render / PAGE_NAME).write_text(LateralStudy.from_json(record.read_text()).markdown())
        return 0
    from msfsu_perception.backends.base import BackendUnavailableError
    from msfsu_perception.checkpoint import CheckpointError

    try:
        study = run(args, argv)
    except (ValueError, FileNotFoundError, CheckpointError, BackendUnavailableError) as error:  # BagError too
        print(f"lateral_study: {error}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / RECORD_NAME).write_text(study.to_json())
    (args.out / PAGE_NAME).write_text(study.markdown())
    return 0


if __name__ == "__main__":
    sys.exit(main())
