"""The pages and README blocks made from committed records, and the tables that compare benchmark runs.

- blocks: `msfsu-results-blocks`, the `<!-- results:NAME -->` blocks of the hand-written pages (README.md, docs/),
  each written by its generator (generators: the committed record read into its type, rendered by that type);
- prose_figures: `msfsu-prose-figures`, every figure typed in those pages' prose registered as a setting or sourced;
- regenerate: `msfsu-regenerate-reports`, every committed closed-loop report made again from its records;
- revision_change, graph_change: `msfsu-revision-change` (one agent's episodes of two runs, paired per route) and
  `msfsu-graph-change` (several networks' in one table); paired_runs: the episodes both read, keyed by route;
- release: `msfsu-model-v3-release`, model v3's release rule and its verdict (release.json);
- rules_change: `msfsu-rules-change`, routes v2 against routes v3 per agent and cell.

The records themselves and their renderers are msfsu_evaluation.records' (and closed_loop.cells' for a report's cells
and paired rows); this package reads them and says where each goes.
"""
