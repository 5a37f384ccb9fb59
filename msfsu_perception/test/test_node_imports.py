"""The live perception node does not load the training data pipeline (rosbags, the torch Dataset,
augmentation, balancing): deploy files are read through msfsu_perception.deploy_files."""

import subprocess
import sys


def test_perception_node_imports_no_training_pipeline():
    probe = ("import sys, msfsu_perception.perception_node; "
             "print(sorted(m for m in sys.modules if m.startswith(('rosbags', 'msfsu_perception.dataset', "
             "'msfsu_perception.bag_index', 'msfsu_perception.bag_paths', 'msfsu_perception.frame_cache', "
             "'msfsu_perception.augmentation', 'msfsu_perception.balancing', 'msfsu_perception.calibration', "
             "'msfsu_perception.train'))))")
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip() == "[]"
