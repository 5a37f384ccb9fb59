"""The MSFSU network (paper section II-D): ResNet V2 fusion encoder, scene decoder, branched policy.

    (B, C, H, W) --encoder--> (B, F, H/32, W/32) --decoder--> (B, 5, H, W) segmentation logits
                                      |
                                      +--GAP--> (B, F) --branch[command]--> steer (B,), speed (B,) [, stop (B,)]

C = 4 (RGB + depth) for "msfsu" and "msf", 3 (RGB) for "su"; F = 2048 for resnet50v2, 512 for
resnet18v2/34v2. "msf" has no decoder. With `stop_output` each branch has a third output, the logit of
"stop here" (the expert's target speed below the control's stop speed), trained as a classification beside the
speed (as LBC's and TCP's controllers treat stopping); in eval mode the network's speed is 0 where that logit is
positive, so every runtime (torch, ONNX, OpenVINO, int8) and every consumer of the speed sees the stop as the
network's own answer. The encoder is written here (no torchvision CPU build, no
downloads) and randomly initialised: the paper does not say it was pretrained. The decoder's kernel
layout (DecoderLayout) deviates from the paper's kernel 3 on purpose; see SceneDecoder.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal, NamedTuple, get_args

import torch
from torch import nn

from msfsu_common.semantic_classes import SemanticClass

Variant = Literal["msfsu", "msf", "su"]
Backbone = Literal["resnet18v2", "resnet34v2", "resnet50v2"]
# "v1": the paper's kernel 3 everywhere (dead border, uneven holes); "v2": kernel = stride (SceneDecoder).
DecoderLayout = Literal["v1", "v2"]
# What a checkpoint written before MSFSUConfig had `decoder_layout` was trained with.
LEGACY_DECODER_LAYOUT: DecoderLayout = "v1"

ENCODER_STRIDE = 32
# Scene decoder of the paper: filters and strides of the five transposed convolutions. The strides are fixed
# (they undo the encoder's 32); the filters are a configuration (MSFSUConfig.decoder_filters), the paper's by default.
PAPER_DECODER_FILTERS: tuple[int, ...] = (512, 128, 64, 16, 5)
DECODER_STRIDES: tuple[int, ...] = (4, 2, 2, 2, 1)
PAPER_DECODER_KERNEL = 3
POLICY_OUTPUTS = 2  # steer, speed; a network with MSFSUConfig.stop_output has a third, the stop logit


class DeconvGeometry(NamedTuple):
    """kernel, stride, padding, output_padding of one nn.ConvTranspose2d (square)."""

    kernel: int
    stride: int
    padding: int
    output_padding: int


def decoder_geometry(layout: DecoderLayout, stride: int) -> DeconvGeometry:
    """The transposed convolution of `layout` that scales its input by exactly `stride`.

    Output size (n - 1) * stride - 2 * padding + kernel + output_padding = n * stride in both layouts.
    """
    if layout == "v1":
        return DeconvGeometry(PAPER_DECODER_KERNEL, stride, 1, stride - 1)
    if stride == 1:
        return DeconvGeometry(3, 1, 1, 0)  # an ordinary 3x3 "same" layer: mixes neighbouring pixels
    return DeconvGeometry(stride, stride, 0, 0)  # every output pixel from exactly one input pixel


@dataclass(frozen=True)
class MSFSUConfig:
    """Architecture of one network; stored in every checkpoint."""

    variant: Variant = "msfsu"
    backbone: Backbone = "resnet50v2"
    input_height: int = 224
    input_width: int = 224
    # The paper does not give the branch widths; CIL (Codevilla et al. 2018) uses 256, 256.
    policy_hidden: tuple[int, ...] = (256, 256)
    dropout: float = 0.5
    num_classes: int = len(SemanticClass)
    num_commands: int = 4
    decoder_layout: DecoderLayout = "v2"  # new networks; checkpoints without the field are "v1"
    # Filters of the five decoder layers; the last is the number of classes. Checkpoints without the field
    # have the paper's. The cpu preset halves the first (training_settings.PRESETS) so its release fits in 30 MB.
    decoder_filters: tuple[int, ...] = PAPER_DECODER_FILTERS
    # A stop output per branch (module doc); checkpoints without the field have none.
    stop_output: bool = False

    def __post_init__(self) -> None:
        if self.variant not in get_args(Variant):
            raise ValueError(f"unknown variant {self.variant!r} (known: {get_args(Variant)})")
        if self.decoder_layout not in get_args(DecoderLayout):
            raise ValueError(
                f"unknown decoder layout {self.decoder_layout!r} (known: {get_args(DecoderLayout)})")
        if self.backbone not in _BACKBONES:
            raise ValueError(f"unknown backbone {self.backbone!r} (known: {tuple(_BACKBONES)})")
        for side in (self.input_height, self.input_width):
            if side <= 0 or side % ENCODER_STRIDE:
                raise ValueError(f"input size must be a positive multiple of {ENCODER_STRIDE}, got {side}")
        if len(self.decoder_filters) != len(DECODER_STRIDES) or min(self.decoder_filters) <= 0:
            raise ValueError(f"decoder_filters must be {len(DECODER_STRIDES)} positive numbers, "
                             f"got {self.decoder_filters}")
        if self.num_classes != self.decoder_filters[-1]:
            raise ValueError(f"the decoder's last layer has {self.decoder_filters[-1]} filters, one per class: "
                             f"{self.num_classes} classes")

    @property
    def in_channels(self) -> int:
        return 3 if self.variant == "su" else 4

    @property
    def has_segmentation(self) -> bool:
        return self.variant != "msf"

    def to_dict(self) -> dict[str, Any]:
        fields = asdict(self)
        fields["policy_hidden"] = list(self.policy_hidden)
        fields["decoder_filters"] = list(self.decoder_filters)
        if not self.stop_output:  # a network without it stores what it stored before the field (older readers too)
            del fields["stop_output"]
        return fields

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> MSFSUConfig:
        """A stored configuration; one without `decoder_layout` predates it and was trained as "v1", one without
        `decoder_filters` has the paper's."""
        return cls(**{"decoder_layout": LEGACY_DECODER_LAYOUT, **fields,
                      "policy_hidden": tuple(fields["policy_hidden"]),
                      "decoder_filters": tuple(fields.get("decoder_filters", PAPER_DECODER_FILTERS))})


class MSFSUOutput(NamedTuple):
    segmentation_logits: torch.Tensor | None  # (B, num_classes, H, W); None for "msf"
    steer: torch.Tensor  # (B,) normalised steering, unbounded (clip at use)
    speed: torch.Tensor  # (B,) target speed / speed_scale; in eval mode 0 where stop_logit > 0
    stop_logit: torch.Tensor | None = None  # (B,) logit of "stop here"; None without MSFSUConfig.stop_output


def _conv3x3(in_channels: int, out_channels: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_channels, out_channels, 3, stride=stride, padding=1, bias=False)


def _conv1x1(in_channels: int, out_channels: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_channels, out_channels, 1, stride=stride, bias=False)


class PreActBasicBlock(nn.Module):
    """BN-ReLU-conv3x3 twice; the projection shortcut (if any) takes the pre-activation."""

    expansion = 1

    def __init__(self, in_channels: int, width: int, stride: int = 1) -> None:
        super().__init__()
        out_channels = width * self.expansion
        self.norm1 = nn.BatchNorm2d(in_channels)
        self.conv1 = _conv3x3(in_channels, width, stride)
        self.norm2 = nn.BatchNorm2d(width)
        self.conv2 = _conv3x3(width, out_channels)
        self.relu = nn.ReLU(inplace=True)
        needs_projection = stride != 1 or in_channels != out_channels
        self.downsample = _conv1x1(in_channels, out_channels, stride) if needs_projection else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        preact = self.relu(self.norm1(x))
        shortcut = x if self.downsample is None else self.downsample(preact)
        out = self.conv1(preact)
        out = self.conv2(self.relu(self.norm2(out)))
        return out + shortcut


class PreActBottleneck(nn.Module):
    """BN-ReLU-conv1x1, BN-ReLU-conv3x3 (stride here), BN-ReLU-conv1x1 (x4 channels)."""

    expansion = 4

    def __init__(self, in_channels: int, width: int, stride: int = 1) -> None:
        super().__init__()
        out_channels = width * self.expansion
        self.norm1 = nn.BatchNorm2d(in_channels)
        self.conv1 = _conv1x1(in_channels, width)
        self.norm2 = nn.BatchNorm2d(width)
        self.conv2 = _conv3x3(width, width, stride)
        self.norm3 = nn.BatchNorm2d(width)
        self.conv3 = _conv1x1(width, out_channels)
        self.relu = nn.ReLU(inplace=True)
        needs_projection = stride != 1 or in_channels != out_channels
        self.downsample = _conv1x1(in_channels, out_channels, stride) if needs_projection else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        preact = self.relu(self.norm1(x))
        shortcut = x if self.downsample is None else self.downsample(preact)
        out = self.conv1(preact)
        out = self.conv2(self.relu(self.norm2(out)))
        out = self.conv3(self.relu(self.norm3(out)))
        return out + shortcut


Block = type[PreActBasicBlock] | type[PreActBottleneck]
_BACKBONES: dict[str, tuple[Block, tuple[int, ...]]] = {
    "resnet18v2": (PreActBasicBlock, (2, 2, 2, 2)),
    "resnet34v2": (PreActBasicBlock, (3, 4, 6, 3)),
    "resnet50v2": (PreActBottleneck, (3, 4, 6, 3)),
}
_STAGE_WIDTHS = (64, 128, 256, 512)


class ResNetV2Encoder(nn.Module):
    """Pre-activation ResNet (He et al. 2016, "Identity mappings"): (B, C, H, W) -> (B, F, H/32, W/32).

    Stem conv7x7/2 + maxpool/2 without normalisation (the first block pre-activates), four stages
    (strides 1, 2, 2, 2), then the final BN + ReLU that V2 needs because blocks end without one.
    Layout as timm's resnetv2: a stage downsamples in its first block's 3x3 conv (Keras'
    ResNet50V2 does it in the last block); both give the paper's 2048 x 7 x 7 at 224 x 224.
    """

    def __init__(self, block: Block, depths: tuple[int, ...], in_channels: int) -> None:
        super().__init__()
        self.stem = nn.Sequential(
            nn.Conv2d(in_channels, 64, 7, stride=2, padding=3, bias=False),
            nn.MaxPool2d(3, stride=2, padding=1),
        )
        stages: list[nn.Module] = []
        channels = 64
        for stage_index, (width, depth) in enumerate(zip(_STAGE_WIDTHS, depths)):
            stride = 1 if stage_index == 0 else 2
            blocks: list[nn.Module] = []
            for block_index in range(depth):
                blocks.append(block(channels, width, stride if block_index == 0 else 1))
                channels = width * block.expansion
            stages.append(nn.Sequential(*blocks))
        self.stages = nn.Sequential(*stages)
        self.final_norm = nn.BatchNorm2d(channels)
        self.final_relu = nn.ReLU(inplace=True)
        self.out_channels = channels

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.final_relu(self.final_norm(self.stages(self.stem(x))))


class SceneDecoder(nn.Module):
    """Five transposed convolutions (paper): (B, F, H/32, W/32) -> (B, 5, H, W) logits.

    Filters 512, 128, 64, 16, 5 (`filters`; the cpu preset's first is 256) and strides 4, 2, 2, 2, 1 as in the
    paper; each layer scales its input exactly by its stride. The kernels depend on `layout` (decoder_geometry):

    "v1", the paper's kernel 3 with padding 1, output_padding stride - 1 (the shipped checkpoints):
    a kernel smaller than its stride leaves holes, and this padding puts them unevenly. Stride 4 on a
    4-wide map reaches output columns [1,1,0,1, 1,1,0,1, 1,1,0,1, 1,1,0,0]: the last two get only the
    bias, a dead 2/16 band on the right and bottom of every segmentation (issue #12); each stride-2
    layer reaches odd columns twice, even ones once and its last column once (checkerboard and border).
    Keras' "same" transposed convolution, which the paper used, holes [1,1,1,0] evenly instead, but
    still leaves a dead column and row in every 4.

    "v2" (new networks): kernel = stride, padding 0 for the strided layers (4, 2, 2, 2), so every
    output position is reached by exactly one input position, with no hole, overlap or border
    (Odena et al. 2016, "Deconvolution and checkerboard artifacts": a kernel divisible by the
    stride); the last layer is an ordinary 3x3, stride 1, padding 1 layer that mixes neighbours and
    has the usual zero-padding border, the same on all four sides. Deviating from the paper's
    kernel 3: +7.3 M parameters in the stride-4 layer of ResNet-50 V2 (2048 x 512 x (16 - 9)), fewer
    FLOPs in total (the stride-2 layers shrink from 9 to 4 taps). Resize-convolution (Odena's other
    remedy) would keep 3x3 kernels but run the 2048 -> 512 layer at 4x the resolution (~15 GFLOP at
    224x224, more than the whole v1 network).

    The paper's softmax on the last layer is left to the loss (cross-entropy on logits) and to argmax.
    """

    def __init__(self, in_channels: int, layout: DecoderLayout,
                 filters_per_layer: tuple[int, ...] = PAPER_DECODER_FILTERS) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        channels = in_channels
        for index, (filters, stride) in enumerate(zip(filters_per_layer, DECODER_STRIDES, strict=True)):
            geometry = decoder_geometry(layout, stride)
            layers.append(
                nn.ConvTranspose2d(
                    channels, filters, geometry.kernel, stride=geometry.stride, padding=geometry.padding,
                    output_padding=geometry.output_padding,
                )
            )
            if index < len(DECODER_STRIDES) - 1:
                layers += [nn.BatchNorm2d(filters), nn.ReLU(inplace=True)]
            channels = filters
        self.layers = nn.Sequential(*layers)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.layers(features)


class BranchedPolicy(nn.Module):
    """One fully connected branch per navigation command: (B, F), (B,) -> (B, outputs) [steer, speed(, stop)].

    All branches run and the command picks one row: a gather instead of Python control flow keeps
    batches with mixed commands in one pass and exports to ONNX as it is.
    """

    def __init__(self, in_features: int, hidden: tuple[int, ...], dropout: float, num_commands: int,
                 outputs: int = POLICY_OUTPUTS) -> None:
        super().__init__()
        self.branches = nn.ModuleList(self._branch(in_features, hidden, dropout, outputs) for _ in range(num_commands))

    @staticmethod
    def _branch(in_features: int, hidden: tuple[int, ...], dropout: float, outputs: int) -> nn.Sequential:
        layers: list[nn.Module] = []
        for width in hidden:
            layers += [nn.Linear(in_features, width), nn.ReLU(inplace=True), nn.Dropout(dropout)]
            in_features = width
        layers.append(nn.Linear(in_features, outputs))
        return nn.Sequential(*layers)

    def forward(self, latent: torch.Tensor, command_index: torch.Tensor) -> torch.Tensor:
        all_branches = torch.stack([branch(latent) for branch in self.branches], dim=1)  # (B, K, 2)
        index = command_index.long().view(-1, 1, 1).expand(-1, 1, all_branches.shape[2])
        return all_branches.gather(1, index).squeeze(1)


class MSFSUNet(nn.Module):
    """forward(x (B, C, H, W), command_index (B,) long in RoadOption.branch_index order) -> MSFSUOutput."""

    def __init__(self, config: MSFSUConfig) -> None:
        super().__init__()
        self.config = config
        block, depths = _BACKBONES[config.backbone]
        self.encoder = ResNetV2Encoder(block, depths, config.in_channels)
        self.decoder = (
            SceneDecoder(self.encoder.out_channels, config.decoder_layout, config.decoder_filters)
            if config.has_segmentation else None
        )
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.policy = BranchedPolicy(
            self.encoder.out_channels, config.policy_hidden, config.dropout, config.num_commands,
            POLICY_OUTPUTS + int(config.stop_output),
        )
        self._init_weights()

    def _init_weights(self) -> None:
        for module in self.modules():
            if isinstance(module, (nn.Conv2d, nn.ConvTranspose2d)):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
                if module.bias is not None:
                    nn.init.zeros_(module.bias)

    def forward(self, x: torch.Tensor, command_index: torch.Tensor) -> MSFSUOutput:
        features = self.encoder(x)
        segmentation = None if self.decoder is None else self.decoder(features)
        actions = self.policy(self.pool(features).flatten(1), command_index)
        if not self.config.stop_output:
            return MSFSUOutput(segmentation, actions[:, 0], actions[:, 1])
        stop_logit = actions[:, 2]
        speed = actions[:, 1] if self.training else actions[:, 1].masked_fill(stop_logit > 0, 0.0)
        return MSFSUOutput(segmentation, actions[:, 0], speed, stop_logit)


def build_model(config: MSFSUConfig) -> MSFSUNet:
    return MSFSUNet(config)


def load_warm_start(network: MSFSUNet, weights: dict[str, torch.Tensor]) -> None:
    """Load a checkpoint's weights into `network`; a network without a stop output warm-starts one with it: each
    branch's last layer keeps its steer and speed rows from `weights` and its fresh stop row (module doc)."""
    state = network.state_dict()
    merged = dict(weights)
    for name, tensor in weights.items():
        target = state.get(name)
        if (name.startswith("policy.") and target is not None and tensor.shape != target.shape
                and tensor.shape[0] == POLICY_OUTPUTS and target.shape[0] == POLICY_OUTPUTS + 1
                and tensor.shape[1:] == target.shape[1:]):
            merged[name] = torch.cat([tensor.to(target.dtype), target[POLICY_OUTPUTS:]])
    network.load_state_dict(merged)
