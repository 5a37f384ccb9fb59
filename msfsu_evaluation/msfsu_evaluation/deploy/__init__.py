"""Deploying a checkpoint: `msfsu-gate` makes what decides the precision the perception node runs.

The node's side (reading the files beside a checkpoint) stays in msfsu_perception: deploy_files (their layout),
calibration (the frames), int8_recipe (layers kept in float), gate_verdicts (thresholds and records). This package
writes them: gate (the command and its steps) and gate_report (the verdicts as markdown). The scoring and the
per-layer sensitivity it runs are msfsu_evaluation.gate_evaluation and msfsu_evaluation.int8_sensitivity.
"""
