"""Deploying a checkpoint: `msfsu-gate` makes what decides the precision the perception node runs.

The node's side (reading the files beside a checkpoint) stays in msfsu_perception: deploy_files (their layout),
calibration (the frames), int8_recipe (layers kept in float), gate_verdicts (thresholds and records). This package
writes them:
- gate: `msfsu-gate`, the command and its steps; scoring: the paths scored on the held-out bags (its last step);
  gate_report: the verdicts as markdown;
- recipe: `msfsu-int8-recipe`, the int8 recipe search (the gate's recipe step); sensitivity: its damage, ranking
  and selection of float layers; quantised_graph: its OpenVINO graph work. Its record and that record's page are
  msfsu_evaluation.records.int8_recipe's.
"""
