"""Model v4 (issue 89): why the decoder variants cross solid lines at junctions, and what the next round should change.

- `lane_places`: where on a route a step or a solid-line crossing lies (junction phase, metres into the turn, the
  side of the route), from the benchmark's route geometry (pure functions; the geometry itself from MetaDrive's map,
  cached).
- `lane_closed_loop`: the committed run directories' crossings, paths and telemetry, per junction passage.
- `lane_model`: the networks on the held-out sample bag (branches, gradients at the trunk, occlusion, weights).
- `lane_diagnosis`: the command that runs them and writes docs/results/model_v4/lane_diagnosis/ (page and record).
"""
