"""Typed benchmark records: each kind reads and writes its committed JSON and renders it.

Rules:
- A record type reads the committed JSON files as they are and writes the JSON its benchmark writes, byte for byte
  (`from_json(text)` / `to_json()`): same keys, same order, same indentation, same final newline or none.
- A key a record does not always carry (a field added after older records were written, a measure a run may skip) is
  None in the type and absent from the JSON.
- Each fact has one renderer: the benchmark page's markdown (`page`, used by the benchmark script) and the README or
  docs block (`block` and its siblings, used by msfsu_evaluation.reports) both live with the record type.
- A page states what the record does not hold (the run's date, command line, options) from a setup its benchmark
  passes in; the record itself is never extended for a page.
- ROS-free: the benchmarks that run graphs import these, never the other way round.

Kinds: `soak` (benchmarks/soak/*.json and its design study), `simulator` (benchmarks/simulator_results.json),
`lockstep` (benchmarks/lockstep_results.json), `suite_time` (benchmarks/suite_time_results.json), `training`
(benchmarks/training_results.json), `network` (benchmarks/network_results.json), `perception`
(benchmarks/perception_results*.json), `gate` (the gate verdicts, <checkpoint>.deploy/*-gate*.json), `int8_profile`
(benchmarks/int8_profile_results.json), `gpu` (benchmarks/gpu_results.json), `stages` (a staged recipe's plan and
finished stages, docs/results/model_v3/{plan.json,stages.jsonl}), `workers` (benchmarks/workers_results.json),
`lateral_study` (the lateral study's record and page), `closed_loop` (a closed-loop report's results.json as the
docs' blocks read it), `default_model` (the default-model recipe's data set and training runs,
docs/results/data/data.json and docs/results/training/*/).
"""
