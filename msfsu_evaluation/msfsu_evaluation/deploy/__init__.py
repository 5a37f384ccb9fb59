"""Deploying a checkpoint: `msfsu-gate` makes what decides the precision the perception node runs.

The node's side (reading the files beside a checkpoint) stays in msfsu_perception: deploy_files (their layout),
calibration (the frames), int8_recipe (layers kept in float), gate_verdicts (thresholds and records). This package
writes them:
- gate: `msfsu-gate`, the command and its steps, and the one writer of verdicts (the perception and GPU benchmarks
  run it: gate.run_gate); scoring: the paths scored on the held-out bags (its last step); gate_report: the verdicts
  as markdown;
- recipe: `msfsu-int8-recipe`, the int8 recipe search (the gate's recipe step); sensitivity: its damage, ranking
  and selection of float layers; quantised_graph: its OpenVINO graph work; recipe_record: its record (the
  sensitivity record, benchmarks/int8_recipes/*.json) and that record's page and docs block.
The gate's logic and the records it writes for the docs live here; msfsu_evaluation.records and reports read them,
never the other way round.
"""
