"""Evaluation of the MSFSU node graph: open-loop bag replay against the bag's ground truth."""
