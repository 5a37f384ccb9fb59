"""A recipe's stages declared once (`Stage`, `Parameter`, `Pipeline`) and run by doit.

Each stage becomes a doit task named as the stage:
- `after` -> `task_dep`: the stages whose products it reads run first (skipped when done);
- `needs` -> `setup`: the stages that put its inputs on this machine (the bags) run first, only when it runs;
- `products` -> `targets` (what it alone makes; `updates`, pages other stages rewrite too, are committed with it
  but are no target); `params` -> `params` (`--name VALUE` after the stage's name, else the environment
  variable, else the default; `msfsu-model-v3 help STAGE` lists them);
- done (`uptodate`): its line in the record's stages.jsonl (a pipeline done by record: holds on every machine, its
  products committed) or its products on disk (a pipeline done by products: one machine's run directory); a stage
  marked `always` runs whenever asked (a collection resumes and skips what it has).

Around each stage's own work the runner keeps its clock (`recording`), appends its line when it ends, and with
`commit` commits its products with the line and the clocks (`commits`). A stage's bad input or a failed command ends it
with one line (`StageFailed`); doit stops at the first failed stage (exit status 1).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from doit.cmd_base import TaskLoader2
from doit.cmd_run import Run
from doit.cmdparse import CmdParseError
from doit.doit_cmd import DoitMain
from doit.exceptions import InvalidCommand, TaskFailed
from doit.loader import generate_tasks
from doit.reporter import ConsoleReporter

from msfsu_common.processes import stop_signals_handled
from msfsu_evaluation.pipelines import commits
from msfsu_evaluation.pipelines.recording import Recording


class StageFailed(Exception):
    """A stage ends here: its message is the one line the run prints."""


@dataclass(frozen=True)
class Parameter:
    """A stage's parameter: doit's `--name` after the stage's name, else the environment variable `env`, else
    `default` (whose type it has)."""

    name: str
    env: str
    default: int | float | str
    help: str

    def option(self) -> dict[str, Any]:
        return {"name": self.name, "long": self.name.replace("_", "-"), "env_var": self.env,
                "type": type(self.default), "default": self.default, "help": self.help}

    def check_environment(self) -> None:
        """An empty variable is unset (as the recipes' `${VAR:-default}` had it); one that is not of the default's
        type is a one-line error before anything runs."""
        value = os.environ.get(self.env)
        if value == "":
            del os.environ[self.env]
        elif value is not None:
            try:
                type(self.default)(value)
            except ValueError:
                raise ValueError(f"{self.env}={value!r} is not {type(self.default).__name__} "
                                 f"({self.name}: {self.help})") from None


def environment(name: str, default: Any) -> Any:
    """A pipeline setting from the environment, of the default's type (empty: the default); ValueError (one line)
    when it does not convert."""
    value = os.environ.get(name, "")
    if value == "":
        return default
    try:
        return type(default)(value)
    except ValueError:
        raise ValueError(f"{name}={value!r} is not {type(default).__name__}") from None


@dataclass(frozen=True)
class Stage:
    name: str
    doc: str
    run: Callable[[StageRun], None]
    products: tuple[str, ...] = ()  # what it makes: committed with its line when it ends (doit's targets)
    updates: tuple[str, ...] = ()  # what it rewrites that other stages write too: committed with it, no target
    inputs: tuple[str, ...] = ()  # files it reads: a missing one fails the stage before it starts
    after: tuple[str, ...] = ()  # stages whose products it reads (doit's task_dep)
    needs: tuple[str, ...] = ()  # stages that put its inputs on this machine, run only when it runs (doit's setup)
    params: tuple[Parameter, ...] = ()
    always: bool = False  # run whenever asked: the work resumes and skips what it has; its line is written once
    rerun_clock: str | None = None  # where its time counts once its line is written (bags collected again)


@dataclass
class Pipeline:
    name: str  # the log's prefix
    title: str  # its commits' subjects begin with it
    command: str  # the console script, named in its commits and messages
    stages: list[Stage]
    recording: Recording
    state: Path  # doit's own database (this machine's: no decision reads it)
    default: list[str] = field(default_factory=list)  # what a run without stage names runs (all stages)
    done_by_record: bool = True  # done: its line in stages.jsonl; else its products on disk
    commit: bool = False
    pages: bool = True  # regenerate the pages' generated blocks (the stages' hours) when a stage ends
    progress_limit_mib: int = 160
    bin: Path = Path(".venv/bin")

    def log(self, message: str) -> None:
        print(f"[{self.name} {datetime.now(timezone.utc):%Y-%m-%dT%H:%M:%SZ}] {message}", flush=True)

    def subject(self, stage: str, what: str) -> str:
        return f"{self.title}, stage {stage}: {what} ({self.command})"

    def generated_pages(self) -> list[str]:
        """The pages with generated blocks, rewritten (the stages' hours among them): what a commit takes with it."""
        if not self.pages:
            return []
        blocks = str(self.bin / "msfsu-results-blocks")
        if subprocess.run([blocks], stdout=subprocess.DEVNULL).returncode != 0:
            raise StageFailed("msfsu-results-blocks could not rewrite the generated blocks")
        listed = subprocess.run([blocks, "--list"], capture_output=True, text=True)
        return listed.stdout.split()


class StageRun:
    """What a stage's work is given: its parameters' values, whether its line is written, commands and commits."""

    def __init__(self, pipeline: Pipeline, stage: Stage, options: dict[str, Any]) -> None:
        self.pipeline, self.stage, self.options = pipeline, stage, options
        self.recorded = pipeline.recording.done(stage.name)

    def log(self, message: str) -> None:
        self.pipeline.log(f"stage {self.stage.name}: {message}")

    def command(self, *argv: str | Path, env: dict[str, str] | None = None, quiet: bool = False) -> None:
        """Runs a command; its failure fails the stage. A SIGINT or SIGTERM to the pipeline while it runs is passed
        on to it (started in a process group of its own, so a Ctrl-C reaches it once, through the pipeline) and it is
        waited for, so it stops as it stops on its own (a training saves the batch it reached, a collection its
        episodes); then the stage stops."""
        words = [str(word) for word in argv]
        name = Path(words[0]).name
        with _signals_passed_on() as passing:
            try:
                process = passing.started(subprocess.Popen(words, env={**os.environ, **(env or {})},
                                                           stdout=subprocess.DEVNULL if quiet else None,
                                                           process_group=0))
            except OSError as error:
                raise StageFailed(f"{words[0]} could not start: {error.strerror}") from None
            status = process.wait()
        received = passing.received
        if received:
            raise StageFailed(f"stopped by {received[0].name}, passed to {name}, which ended with status {status}: "
                              "the same command goes on from where it stopped")
        if status != 0:
            raise StageFailed(f"{name} exited with status {status}")

    def tool(self, name: str, *args: str | Path, **kwargs: Any) -> None:
        """The project's console script `name` (the checkout's venv) with `args`."""
        self.command(self.pipeline.bin / name, *args, **kwargs)

    def commit(self, what: str, paths: Sequence[str]) -> None:
        """With COMMIT, `paths` and the regenerated pages as one commit (none when nothing changed)."""
        if not self.pipeline.commit:
            return
        paths = [*paths, *self.pipeline.generated_pages()]
        if commits.commit_paths(self.pipeline.subject(self.stage.name, what), paths) is commits.Outcome.FAILED:
            raise StageFailed(f"git could not commit {what}")

    @contextmanager
    def progress(self, what: str, directory: str, watched: str, poll_s: float, settle_s: float) -> Iterator[None]:
        """With COMMIT, while the block runs: `directory`, the clocks and the pages they make committed after each
        change of `watched` (one commit, amended: `commits.commit_progress`), and once more when the block ends
        without an error."""
        if not self.pipeline.commit:
            yield
            return
        pipeline = self.pipeline
        subject = pipeline.subject(self.stage.name, what)

        def commit() -> commits.Outcome:
            try:
                paths = [*pipeline.generated_pages(), directory, str(pipeline.recording.clocks)]
            except StageFailed:
                return commits.Outcome.FAILED
            outcome, size = commits.commit_progress(subject, paths, pipeline.progress_limit_mib)
            if outcome is commits.Outcome.UNDONE:
                self.log(f"{what} not committed: the unsubmitted commits would have {size} MiB of diffs (limit "
                         f"{pipeline.progress_limit_mib} MiB, PROGRESS_LIMIT_MIB); it stays in {directory}")
            return outcome

        committer = commits.ProgressCommitter(commit, Path(watched), poll_s, settle_s, pipeline.recording.lock)
        committer.start()
        try:
            yield
        except BaseException:
            committer.stop(final=False)
            raise
        committer.stop(final=True)


def _execute(pipeline: Pipeline, stage: Stage, task: Any) -> TaskFailed | None:
    """doit's action of a stage: its inputs checked, its work under its clock, its line, its products committed."""
    try:
        missing = [path for path in stage.inputs if not Path(path).exists()]
        if missing:
            raise StageFailed(f"its input {missing[0]} is missing")
        run = StageRun(pipeline, stage, dict(task.options or {}))
        clock = stage.rerun_clock if run.recorded and stage.rerun_clock else stage.name
        started = time.time()
        with pipeline.recording.clock(clock):
            stage.run(run)
        pipeline.recording.finish(stage.name)
        pages = pipeline.generated_pages()  # the stage's hours into the pages' blocks
        pipeline.log(f"stage {stage.name} done ({int(time.time() - started) // 60} min in this invocation)")
        if pipeline.commit:
            missing = [path for path in (*stage.products, *stage.updates) if not Path(path).exists()]
            if missing:
                raise StageFailed(f"its product {missing[0]} is missing")
            paths = [str(pipeline.recording.stages_file), *pages, str(pipeline.recording.clocks), *stage.products,
                     *stage.updates]
            if commits.commit_paths(pipeline.subject(stage.name, "its product and hours"),
                                    paths) is commits.Outcome.FAILED:
                raise StageFailed("git could not commit its product")
            size = commits.unsubmitted_mib()
            if size > commits.SUBMISSION_MIB:
                pipeline.log(f"WARNING: the unsubmitted commits have {size} MiB of diffs, over the "
                             f"{commits.SUBMISSION_MIB} MiB a submission takes: squash the progress commits before "
                             "the session ends")
    except StageFailed as failure:
        return TaskFailed(f"stage {stage.name}: {failure}")
    return None


class _PassOn:
    """The stop signals this process received while a command ran, each sent on to the command (one received before
    the command had started is sent to it once it has)."""

    def __init__(self) -> None:
        self.received: list[signal.Signals] = []
        self.process: subprocess.Popen[bytes] | None = None
        self.unsent = 0  # received before the process was there

    def __call__(self, signum: int, frame: object) -> None:
        self.received.append(signal.Signals(signum))
        if self.process is None:
            self.unsent += 1
        elif self.process.returncode is None:
            self.process.send_signal(signum)

    def started(self, process: subprocess.Popen[bytes]) -> subprocess.Popen[bytes]:
        """`process`, sent what came before it started; from here on the handler sends what it receives."""
        self.process = process
        for signum in self.received[:self.unsent]:
            process.send_signal(signum)
        return process


@contextmanager
def _signals_passed_on() -> Iterator[_PassOn]:
    """While the block runs, SIGINT and SIGTERM to this process are sent on to the command it starts (and listed in
    `received`) instead of stopping this one; the handlers from before are back at its end. The handlers are there
    before the command starts, so no stop is lost in between, and the command starts with both signals at their
    default (exec resets a handled signal), even where this process began with them ignored, as a shell's background
    job ignores SIGINT. Outside the main thread, where Python takes no handlers, nothing is passed on."""
    passing = _PassOn()
    if threading.current_thread() is not threading.main_thread():
        yield passing
        return
    with stop_signals_handled(passing):
        yield passing


class StageReporter(ConsoleReporter):
    """doit's console reporter in the pipeline's log lines; a failed stage in one line on stderr."""

    pipeline: Pipeline  # set by the loader

    def execute_task(self, task: Any) -> None:
        self.pipeline.log(f"stage {task.name}")

    def skip_uptodate(self, task: Any) -> None:
        self.pipeline.log(f"stage {task.name}: done")

    def skip_ignore(self, task: Any) -> None:
        self.pipeline.log(f"stage {task.name}: ignored (doit ignore)")

    def add_failure(self, task: Any, fail: Any) -> None:
        print(f"{self.pipeline.command}: {fail.get_msg().strip()}", file=sys.stderr, flush=True)

    def complete_run(self) -> None:
        for error in self.runtime_errors:
            print(f"{self.pipeline.command}: {error}", file=sys.stderr, flush=True)


class Recorded:
    """A stage's `uptodate`: its line is in the record's stages.jsonl."""

    def __init__(self, recording: Recording, stage: str) -> None:
        self.recording, self.stage = recording, stage

    def __call__(self) -> bool:
        return self.recording.done(self.stage)

    def __repr__(self) -> str:
        return f"its line in {self.recording.stages_file}"


class PipelineLoader(TaskLoader2):
    def __init__(self, pipeline: Pipeline) -> None:
        super().__init__()
        self.pipeline = pipeline

    def load_doit_config(self) -> dict[str, Any]:
        reporter = type("Reporter", (StageReporter,), {"pipeline": self.pipeline})
        default = self.pipeline.default or [stage.name for stage in self.pipeline.stages]
        return {"dep_file": str(self.pipeline.state), "backend": "json", "verbosity": 2, "reporter": reporter,
                "sort": "definition", "default_tasks": default}

    def load_tasks(self, cmd: Any, pos_args: Any) -> list[Any]:
        tasks = []
        for stage in self.pipeline.stages:
            task: dict[str, Any] = {
                "actions": [(_execute, [self.pipeline, stage])], "doc": stage.doc, "targets": list(stage.products),
                "task_dep": list(stage.after), "setup": list(stage.needs),
                "params": [parameter.option() for parameter in stage.params], "io": {"capture": False},
                "verbosity": 2}
            if not stage.always:
                task["uptodate"] = [Recorded(self.pipeline.recording, stage.name) if self.pipeline.done_by_record
                                    else True]
            tasks += generate_tasks(stage.name, task, stage.doc)
        return tasks


def run_command(stages: Sequence[str]) -> type[Run]:
    """doit's `run`, naming the stages when asked for one it does not have, and a parameter's bad value, in one line
    (doit's take three and two)."""
    class RunStages(Run):
        name = "run"

        def execute(self, params: Any, args: Any) -> int:
            try:
                return super().execute(params, args)
            except InvalidCommand as error:
                if error.not_found is None:
                    raise
                raise InvalidCommand(f'no stage "{error.not_found}" (stages: {", ".join(stages)})') from None
            except CmdParseError as error:
                raise CmdParseError(" ".join(str(error).split())) from None

    return RunStages


def repository_root() -> Path:
    """The checkout the recipe runs in: the git worktree around the working directory."""
    top = subprocess.run(["git", "rev-parse", "--show-toplevel"], capture_output=True, text=True)
    if top.returncode != 0:
        raise ValueError(f"{Path.cwd()} is not inside a git checkout: run it from the repository")
    return Path(top.stdout.strip())


def main(build: Callable[[], Pipeline], argv: Sequence[str] | None, command: str) -> int:
    """Builds the pipeline from the environment in the checkout's root and runs doit's command line on it."""
    try:
        os.chdir(repository_root())
        pipeline = build()
        for stage in pipeline.stages:
            for parameter in stage.params:
                parameter.check_environment()
    except ValueError as error:
        print(f"{command}: {error}", file=sys.stderr)
        return 2
    pipeline.state.parent.mkdir(parents=True, exist_ok=True)
    if pipeline.commit:
        base = commits.git("rev-parse", "--short", commits.submit_base()).stdout.strip()
        pipeline.log(f"commits not yet submitted: after {base} ({commits.unsubmitted_mib()} MiB of diffs; SUBMIT_BASE "
                     "names another base)")
    commands = tuple(run_command([stage.name for stage in pipeline.stages]) if cmd is Run else cmd
                     for cmd in DoitMain.DOIT_CMDS)
    runner = type("Main", (DoitMain,), {"BIN_NAME": command, "DOIT_CMDS": commands})
    return runner(PipelineLoader(pipeline), config_filenames=()).run(list(sys.argv[1:] if argv is None else argv))

