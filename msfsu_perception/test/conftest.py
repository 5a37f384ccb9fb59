"""Tests share two CPU cores with other work: one intra-op thread each."""

import torch

torch.set_num_threads(1)
