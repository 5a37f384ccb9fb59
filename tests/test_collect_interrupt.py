"""msfsu-collect with simulator workers, stopped by a signal: the parent reports the interrupt, the workers end
with it, nothing is printed as a crash and no half-written bag is taken for a finished one. Before, `kill -INT`
to a background collection did nothing, a stop to the process group killed each worker with a traceback, and the
pool then waited forever for the jobs those workers held."""

import signal
import subprocess
import sys
import time

import pytest
from process_hygiene import descendants, wait_until_gone

WORKERS = 2


# Each case starts two simulators: the slow suite's.
@pytest.mark.slow
@pytest.mark.parametrize("group", [pytest.param(False, id="kill-int-parent"), pytest.param(True, id="ctrl-c-group")])
def test_a_stop_signal_ends_collection_workers_quietly(tmp_path, group):
    """SIGINT to the parent alone, as `kill -INT` to a background job (started with SIGINT ignored), or to its
    whole process group, as a terminal's Ctrl-C."""
    output = tmp_path / "data"
    log = tmp_path / "collect.log"
    with log.open("w") as stream:
        collect = subprocess.Popen(
            [sys.executable, "-m", "msfsu_sim.collect", "--output", str(output), "--split", "train",
             "--episodes", "1", "--towns", "town_a", "--weathers", "clear_noon", "--traffic", "empty", "regular",
             "--max-steps", "300", "--workers", str(WORKERS)],
            stdout=stream, stderr=subprocess.STDOUT, start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    partial = output / "train" / ".partial"
    deadline = time.monotonic() + 300
    while not (partial.is_dir() and any(partial.iterdir())):  # a worker is recording an episode
        assert collect.poll() is None and time.monotonic() < deadline, log.read_text()[-3000:]
        time.sleep(0.5)
    time.sleep(2.0)
    tree = descendants(collect.pid)
    if group:
        subprocess.run(["kill", "-INT", "--", f"-{collect.pid}"], check=True)
    else:
        collect.send_signal(signal.SIGINT)
    try:
        code = collect.wait(timeout=60)
    except subprocess.TimeoutExpired:
        collect.kill()
        raise AssertionError("msfsu-collect did not stop within 60 s:\n" + log.read_text()[-3000:]) from None
    left = wait_until_gone(tree, 30.0)
    for pid in left:  # clean up what a failing run left
        subprocess.run(["kill", "-KILL", str(pid)], check=False)
    text = log.read_text()
    assert code == 1 and "msfsu-collect: interrupted (re-run the same command to resume)" in text, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    assert not left, text[-3000:]
    cut = {path.name for path in partial.iterdir()}  # the episodes under way: not promoted to finished bags
    assert cut and not cut & {path.name for path in (output / "train").iterdir()}
