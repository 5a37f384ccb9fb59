"""The long recipes as pipelines that doit runs (`msfsu-model-v3`, `msfsu-default-model`).

doit (pydoit.org) holds the stages as tasks: their order (`task_dep`), the stages that put a stage's inputs on this
machine first (`setup`: run only when the stage itself runs), their products (`targets`), their parameters (`params`,
each from its environment variable or the command line) and when a stage is done (`uptodate`); it selects, skips and
runs them and gives the usual commands (`list`, `info`, `help STAGE`, `ignore`). What no pipeline tool does is written
here by hand:

- `recording`: each stage's wall hours over every invocation on every machine (a clock per invocation, beating while
  the stage runs) and its line in the recipe's `stages.jsonl` (`records.stages.StageRecord`) when it ends;
- `commits`: a stage's products committed when it ends, and its progress while it runs (a training stage's snapshot
  after every epoch, a benchmark's episodes so far) as one commit amended while it is the newest and not yet
  submitted, never past the submission's size limit;
- `runner`: the stage declaration (`Stage`, `Parameter`) and its translation into doit's tasks.

The recipes themselves: `model_v3` and `default_model`.
"""
