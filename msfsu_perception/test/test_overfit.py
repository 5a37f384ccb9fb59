import numpy as np
import torch

from msfsu_perception.losses import msfsu_loss
from msfsu_perception.model import MSFSUConfig, build_model
from msfsu_perception.preprocessing import PreprocessConfig, preprocess_frame, preprocess_labels
from msfsu_common.semantic_classes import CLASS_COLOURS
from msfsu_perception.synthetic import render_scene

STEPS = 60


def _tiny_dataset(count: int = 8):
    """count scenes at 64x64: inputs, command index, steer, normalised speed, class ids."""
    preprocess = PreprocessConfig(input_height=64, input_width=64)
    rng = np.random.default_rng(0)
    steer = rng.uniform(-0.6, 0.6, count).astype(np.float32)
    stopped = np.arange(count) % 3 == 0
    inputs, labels = [], []
    for value, stop in zip(steer, stopped):
        class_ids, depth = render_scene(float(value), bool(stop), 128, 128)
        inputs.append(preprocess_frame(CLASS_COLOURS[class_ids], depth, preprocess))
        labels.append(preprocess_labels(class_ids, preprocess))
    speed = np.where(stopped, 0.0, 0.8).astype(np.float32)
    return (
        torch.from_numpy(np.stack(inputs)),
        torch.arange(count) % 4,
        torch.from_numpy(steer),
        torch.from_numpy(speed),
        torch.from_numpy(np.stack(labels).astype(np.int64)),
    )


def test_resnet18v2_overfits_a_tiny_synthetic_dataset():
    torch.manual_seed(0)
    inputs, commands, steer, speed, class_ids = _tiny_dataset()
    model = build_model(MSFSUConfig(variant="msfsu", backbone="resnet18v2", input_height=64, input_width=64))
    optimizer = torch.optim.NAdam(model.parameters(), lr=1e-3)
    first_loss = None
    for _ in range(STEPS):
        terms = msfsu_loss(model(inputs, commands), steer, speed, class_ids)
        optimizer.zero_grad()
        terms.total.backward()
        optimizer.step()
        first_loss = first_loss or terms.total.item()
    model.eval()  # dropout 0.5 on 8 samples makes training-mode losses too noisy to compare
    with torch.no_grad():
        final = msfsu_loss(model(inputs, commands), steer, speed, class_ids)
    assert final.total.item() < first_loss / 10, (first_loss, final)
    assert final.scene.item() < 0.5 * np.log(5) / 5  # segmentation learnt, not only the actions
