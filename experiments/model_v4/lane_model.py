"""The networks on the same frames of held-out bags (torch fp32 on the CPU, eval mode), four experiments that can fail.

1. **Every branch on every frame** (`branches`): each frame's pooled features through every command's branch: the
   signed steer error against the expert's label per frame group (lateral_study.FrameGroups: LEFT approach / turn,
   ...), each branch's spread over the frames and its correlation with the label. A LEFT branch that steers left on
   frames where the expert goes straight (other commands' frames, the approach) carries a bias of its own; one that
   does not vary with the frame has stopped looking at it.
2. **The trunk's gradient by loss term** (`gradients`): at the trained weights, the gradient on the encoder of the
   steer loss of each command's frames (lambda1 times eq. 6), of the speed loss, the scene loss (lambda3 times eq. 8)
   and the stop loss where there is one, each summed over its frames; their norms per encoder stage and the cosine of
   each steer gradient with the scene gradient. A scene gradient many times a branch's steer gradient, pointing
   against it, is a trunk that training moves for the scene at the branch's cost.
3. **What the LEFT branch looks at** (`occlusion`): the LEFT branch's steer on the LEFT frames with a part of the
   input replaced by its mean over the frames (the upper or lower half, the left or right half, the depth channel,
   the colour), and the share of |gradient x input| of the LEFT steer in each part. A network that turns in early
   because it reads the junction's opening on the left shows it as a steer that moves right when the left half goes.
4. **Where training moved the weights** (`weights`): per part (encoder stage, decoder, each branch's layers), the
   relative change ||W_b - W_a|| / ||W_a|| between a checkpoint and the one it was warm-started from.

Intervals: 95 % bootstrap over 1-second blocks of frames (lateral_study.cluster_bootstrap with blocks of
BLOCK_FRAMES): the frames of one bag are a continuous drive, so frames are not independent; with one bag the blocks
are all there is, and the intervals say what these frames can tell, not what another drive would show.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.model_v4.lane_closed_loop import interval
from msfsu_common.road_option import RoadOption

BLOCK_FRAMES = 10  # 1 s at 10 Hz
OCCLUSIONS = ("upper half", "lower half", "left half", "right half", "depth", "colour")
BATCH = 33
GROUPS = ("LEFT approach", "LEFT turn", "RIGHT approach", "RIGHT turn", "STRAIGHT", "LANE_FOLLOW")  # FrameGroups'
OUTPUT_LAYER = "6"  # the index of a branch's last Linear in its Sequential (256-256 hidden: Linear, ReLU, Dropout x 2)


@dataclass
class Frames:
    """The pooled frames every network is run on (the same stamps for all)."""

    names: list[str]  # bag names
    inputs: dict[bool, np.ndarray]  # with depth (C=4) / without (C=3): (N, C, H, W) float32
    command: np.ndarray  # (N,) RoadOption values
    steer: np.ndarray  # (N,) the expert's label
    speed: np.ndarray  # (N,) m/s
    class_ids: np.ndarray  # (N, H, W) int64
    group: np.ndarray  # (N,) lateral_study.FrameGroups names
    block: np.ndarray  # (N,) bootstrap cluster: 1 s blocks, unique over bags


def load_frames(bags: Sequence[Path], checkpoints: Sequence[Path], cache_dir: Path, per_bag: int | None = None
                ) -> Frames:
    """The bags' frames (at most `per_bag` of each, evenly spaced) as every network's preprocessing makes them."""
    from msfsu_evaluation.deploy.scoring import load_held_out
    from msfsu_evaluation.lateral_study import FrameGroups, common_frames
    from msfsu_perception.bag_topics import BagTopics
    from msfsu_perception.checkpoint import load_checkpoint
    from msfsu_perception.deploy_files import cached_inputs

    preprocesses = list(dict.fromkeys(load_checkpoint(path).preprocess for path in checkpoints))
    loaded = common_frames({p: load_held_out(list(bags), BagTopics(), p, cache_dir, per_bag) for p in preprocesses})
    inputs: dict[bool, np.ndarray] = {}
    for preprocess, held in loaded.items():
        rows = []
        for bag in held:
            for index in bag.indices:
                row = bag.truth.rows[index]
                out = np.empty((preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32)
                depth = bag.truth.cache.depth[row] if preprocess.use_depth and bag.truth.cache.depth is not None \
                    else None
                rows.append(cached_inputs(bag.truth.cache.rgb[row], depth, out))
        inputs[preprocess.use_depth] = np.stack(rows)
    held = next(iter(loaded.values()))
    command = np.concatenate([bag.truth.command[bag.indices] for bag in held]).astype(np.int64)
    steer = np.concatenate([bag.steer for bag in held])
    speed = np.concatenate([bag.truth.target_speed[bag.indices] for bag in held]).astype(np.float64)
    class_ids = np.concatenate([bag.labels() for bag in held]).astype(np.int64)
    blocks, offset = [], 0
    for bag in held:
        blocks.append(offset + np.arange(len(bag)) // BLOCK_FRAMES)
        offset = int(blocks[-1].max()) + 1 if len(bag) else offset
    return Frames([bag.path.name for bag in held], inputs, command, steer, speed, class_ids,
                  FrameGroups.of(held).group, np.concatenate(blocks))


def _model(checkpoint: Path):
    import torch

    from msfsu_perception.checkpoint import load_checkpoint

    loaded = load_checkpoint(checkpoint)
    model = loaded.model.eval()
    for parameter in model.parameters():
        parameter.requires_grad_(False)
    return loaded, model, torch


def branch_outputs(checkpoint: Path, frames: Frames) -> np.ndarray:
    """(N, 4) each branch's steer (RoadOption branch order) on every frame."""
    loaded, model, torch = _model(checkpoint)
    x = frames.inputs[loaded.preprocess.use_depth]
    steer = []
    with torch.no_grad():
        for start in range(0, len(x), BATCH):
            latent = model.pool(model.encoder(torch.from_numpy(x[start:start + BATCH]))).flatten(1)
            steer.append(torch.stack([branch(latent)[:, 0] for branch in model.policy.branches], 1).numpy())
    return np.concatenate(steer).astype(np.float64)


def branches(name: str, steer: np.ndarray, frames: Frames) -> list[dict]:
    """Per frame group and branch: frames, mean signed error (interval over blocks); per branch over all frames: its
    spread and its correlation with the label."""
    rows = []
    for group in [g for g in GROUPS if (frames.group == g).any()]:
        mask = frames.group == group
        for option in RoadOption:
            error = steer[mask, option.branch_index] - frames.steer[mask]
            rows.append({"network": name, "frames_of": group, "branch": option.name, "frames": int(mask.sum()),
                         "signed_error": round(float(error.mean()), 4), "ci95": interval(error, frames.block[mask]),
                         "own": option.name == group.split()[0]})
    for option in RoadOption:
        values = steer[:, option.branch_index]
        own = frames.command == option.value
        corr = (float(np.corrcoef(values[own], frames.steer[own])[0, 1])
                if own.sum() > 2 and values[own].std() > 0 and frames.steer[own].std() > 0 else None)
        rows.append({"network": name, "frames_of": "all", "branch": option.name, "frames": len(values),
                     "std": round(float(values.std()), 4), "own_frames": int(own.sum()),
                     "own_std": round(float(values[own].std()), 4) if own.any() else None,
                     "expert_own_std": round(float(frames.steer[own].std()), 4) if own.any() else None,
                     "own_correlation": None if corr is None else round(corr, 3)})
    return rows


def _stages(model) -> list[tuple[str, list]]:
    """The encoder's parameters by its top-level children (stem, stages, final norm)."""
    stages = []
    for child_name, child in model.encoder.named_children():
        parameters = list(child.parameters())
        if parameters:
            stages.append((child_name, parameters))
    return stages


def gradients(name: str, checkpoint: Path, frames: Frames) -> list[dict]:
    """Per loss term: the norm of its summed gradient on the encoder, per stage and in all, and its cosine with the
    scene gradient; each command's steer loss on that command's frames alone."""
    from msfsu_perception.losses import LossConfig, scene_loss, speed_loss, stop_loss, weighted_steer_loss

    loaded, model, torch = _model(checkpoint)
    config = LossConfig()
    stages = _stages(model)
    parameters = [p for _, group in stages for p in group]
    for parameter in parameters:
        parameter.requires_grad_(True)
    x = frames.inputs[loaded.preprocess.use_depth]
    groups = [group for group in GROUPS if (frames.group == group).any()]
    terms = [f"steer {group}" for group in groups]
    terms += ["speed"] + (["scene"] if model.config.has_segmentation else []) + (
        ["stop"] if model.config.stop_output else [])
    totals = {term: [torch.zeros_like(p) for p in parameters] for term in terms}
    counts = {term: 0 for term in terms}
    for start in range(0, len(x), BATCH):
        chunk = slice(start, start + BATCH)
        command = torch.from_numpy(np.array([RoadOption(int(c)).branch_index for c in frames.command[chunk]]))
        output = model(torch.from_numpy(x[chunk]), command)
        steer_gt = torch.from_numpy(frames.steer[chunk].astype(np.float32))
        speed_gt = torch.from_numpy((frames.speed[chunk] / loaded.speed_scale).astype(np.float32))
        losses = {}
        for group in groups:
            mask = torch.from_numpy(frames.group[chunk] == group)
            if mask.any():
                losses[f"steer {group}"] = (int(mask.sum()), config.steer_weight * weighted_steer_loss(
                    output.steer[mask], steer_gt[mask], config.alpha, config.beta, config.gamma))
        batch = len(steer_gt)
        losses["speed"] = (batch, config.speed_weight * speed_loss(output.speed, speed_gt, config.stop_below,
                                                                   config.stop_speed_weight))
        if "scene" in terms:
            losses["scene"] = (batch, config.scene_weight * scene_loss(
                output.segmentation_logits, torch.from_numpy(frames.class_ids[chunk])))
        if "stop" in terms:
            losses["stop"] = (batch, config.stop_weight * stop_loss(output.stop_logit, speed_gt, config.stop_below))
        names = list(losses)
        for index, term in enumerate(names):
            size, loss = losses[term]
            grads = torch.autograd.grad(size * loss, parameters, retain_graph=index < len(names) - 1,
                                        allow_unused=True)
            for total, grad in zip(totals[term], grads):
                if grad is not None:
                    total.add_(grad)
            counts[term] += size
    sizes = [len(group) for _, group in stages]
    rows = []
    flat = {term: torch.cat([g.flatten() for g in totals[term]]).double() for term in terms}
    for term in terms:
        row = {"network": name, "term": term, "frames": counts[term], "norm": float(flat[term].norm()),
               "stage_norms": {}}
        position = 0
        for (stage, _), size in zip(stages, sizes):
            vector = torch.cat([g.flatten() for g in totals[term][position:position + size]]).double()
            row["stage_norms"][stage] = round(float(vector.norm()), 4)
            position += size
        if "scene" in flat and term != "scene":
            scene = flat["scene"]
            row["cosine_with_scene"] = round(float(flat[term] @ scene) / max(float(flat[term].norm() * scene.norm()),
                                                                             1e-30), 3)
            row["scene_over_term"] = round(float(scene.norm()) / max(float(flat[term].norm()), 1e-30), 3)
        row["norm"] = round(row["norm"], 4)
        rows.append(row)
    return rows


def _fill(x: np.ndarray, part: str, use_depth: bool, fill_from: np.ndarray) -> np.ndarray | None:
    """x (N, C, H, W) with `part` replaced by the per-channel mean of `fill_from`'s frames (None: no such part)."""
    out = x.copy()
    mean = fill_from.mean(axis=(0, 2, 3), keepdims=True)
    height, width = x.shape[2], x.shape[3]
    regions = {"upper half": (slice(None), slice(None), slice(0, height // 2), slice(None)),
               "lower half": (slice(None), slice(None), slice(height // 2, None), slice(None)),
               "left half": (slice(None), slice(None), slice(None), slice(0, width // 2)),
               "right half": (slice(None), slice(None), slice(None), slice(width // 2, None))}
    if part in regions:
        region = regions[part]
        out[region] = np.broadcast_to(mean, x.shape)[region]
    elif part == "depth":
        if not use_depth:
            return None
        out[:, 3:] = mean[:, 3:]
    elif part == "colour":
        out[:, :3] = mean[:, :3]
    return out


def occlusion(name: str, checkpoint: Path, frames: Frames) -> list[dict]:
    """The LEFT branch on the LEFT approach frames and on the LEFT turn frames, each with each part filled: mean steer
    change (interval over blocks) and the filled input's signed error; and the share of |gradient x input| of the
    LEFT steer in each region."""
    loaded, model, torch = _model(checkpoint)
    use_depth = loaded.preprocess.use_depth
    branch = model.policy.branches[RoadOption.LEFT.branch_index]

    def left_steer(inputs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return np.concatenate([branch(model.pool(model.encoder(torch.from_numpy(inputs[s:s + BATCH]))).flatten(1)
                                          )[:, 0].numpy() for s in range(0, len(inputs), BATCH)]).astype(np.float64)

    rows = []
    fill_from = frames.inputs[use_depth][frames.command == RoadOption.LEFT.value]  # the means every fill uses
    for group in ("LEFT approach", "LEFT turn"):
        chosen = frames.group == group
        if chosen.sum() < 2:
            continue
        x = frames.inputs[use_depth][chosen]
        label, blocks = frames.steer[chosen], frames.block[chosen]
        clean = left_steer(x)
        rows.append({"network": name, "frames_of": group, "part": "none", "frames": int(chosen.sum()),
                     "steer": round(float(clean.mean()), 4), "signed_error": round(float((clean - label).mean()), 4),
                     "ci95": interval(clean - label, blocks)})
        for part in OCCLUSIONS:
            filled = _fill(x, part, use_depth, fill_from)
            if filled is None:
                continue
            steer = left_steer(filled)
            change = steer - clean
            rows.append({"network": name, "frames_of": group, "part": part, "frames": int(chosen.sum()),
                         "steer": round(float(steer.mean()), 4), "change": round(float(change.mean()), 4),
                         "change_ci95": interval(change, blocks),
                         "signed_error": round(float((steer - label).mean()), 4)})
        tensor = torch.from_numpy(x).requires_grad_(True)
        attribution = []
        for start in range(0, len(x), BATCH):
            part_of = tensor[start:start + BATCH]
            steer = branch(model.pool(model.encoder(part_of)).flatten(1))[:, 0]
            (grad,) = torch.autograd.grad(steer.sum(), part_of)
            attribution.append((grad * part_of).abs().detach().numpy())
        attribution = np.concatenate(attribution)
        height, width = x.shape[2], x.shape[3]
        total = float(attribution.sum())
        shares = {"upper half": attribution[:, :, :height // 2].sum(),
                  "lower half": attribution[:, :, height // 2:].sum(),
                  "left half": attribution[:, :, :, :width // 2].sum(),
                  "right half": attribution[:, :, :, width // 2:].sum(), "colour": attribution[:, :3].sum()}
        if use_depth:
            shares["depth"] = attribution[:, 3:].sum()
        rows.append({"network": name, "frames_of": group, "part": "attribution", "frames": int(chosen.sum()),
                     "shares": {part: round(float(value) / max(total, 1e-30), 3) for part, value in shares.items()}})
    return rows


def _parts(state: Mapping[str, object]) -> dict[str, list[str]]:
    parts: dict[str, list[str]] = {}
    for key in state:
        pieces = key.split(".")
        if pieces[0] == "encoder":
            part = f"encoder {pieces[1]}"
        elif pieces[0] == "policy":
            part = f"branch {RoadOption(int(pieces[2]) + 1).name} layer {pieces[3]}"
            if pieces[3] == OUTPUT_LAYER:  # its rows apart: steer, speed
                for row, name in enumerate(("steer", "speed")):
                    parts.setdefault(f"{part} {name} row", []).append(f"{key}#{row}")
                continue
        else:
            part = pieces[0]
        parts.setdefault(part, []).append(key)
    return parts


def weights(name: str, checkpoint: Path, base: Path) -> list[dict]:
    """Per part: ||W - W_base|| / ||W_base|| over its weights and biases (batch norms' running statistics left out);
    a branch's output layer by its steer row and its speed row (a stop row new in `checkpoint` is in neither)."""
    import torch

    from msfsu_perception.checkpoint import load_checkpoint

    after = load_checkpoint(checkpoint).model.state_dict()
    before = load_checkpoint(base).model.state_dict()
    rows = []
    for part, keys in _parts(before).items():
        delta = norm = 0.0
        for item in keys:
            key, _, row = item.partition("#")
            if key not in after or "running" in key or "num_batches" in key:
                continue
            a, b = before[key].double(), after[key].double()
            if row:
                a, b = a[int(row)], b[int(row)]
            delta += float(torch.sum((b - a) ** 2))
            norm += float(torch.sum(a ** 2))
        if norm > 0:
            rows.append({"network": name, "base": base.as_posix(), "part": part,
                         "relative_change": round((delta / norm) ** 0.5, 4)})
    return rows
