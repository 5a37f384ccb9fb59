"""msfsu-benchmark stopped by a signal to its parent process alone: its simulator workers and the node
graph a worker drives end too (they used to run on), the records so far stay, and a re-run resumes."""

import json
import signal
import subprocess
import sys
import time

import pytest
from process_hygiene import descendants, fast_dds_files, leaked_shm_files, wait_until_gone

GRAPH_PROCESSES = 4  # the worker's launcher and its route, perception and control nodes


# both signals reach the same handler (interrupt_on_signals); SIGTERM's run is the slow suite's
@pytest.mark.parametrize("stop", [pytest.param(signal.SIGTERM, id="sigterm", marks=pytest.mark.slow),
                                  pytest.param(signal.SIGINT, id="sigint")])
def test_a_signal_to_the_parent_stops_workers_and_graphs(tiny_checkpoint, tmp_path, stop):
    """SIGINT as a shell's background job gets it: started with SIGINT ignored (`kill -INT` must still work)."""
    out = tmp_path / "bench"
    present_before = fast_dds_files()
    log = tmp_path / "benchmark.log"
    with log.open("w") as output:  # its own session: only the parent gets the signal, as from `kill PID`
        benchmark = subprocess.Popen(
            [sys.executable, "-m", "msfsu_evaluation.closed_loop", "--checkpoint", f"tiny={tiny_checkpoint}",
             "--suite", "smoke", "--tasks", "straight", "--out", str(out)],
            stdout=output, stderr=subprocess.STDOUT, start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    deadline = time.monotonic() + 300
    while len(tree := descendants(benchmark.pid)) < 1 + GRAPH_PROCESSES:  # the worker, then its graph
        assert benchmark.poll() is None and time.monotonic() < deadline, log.read_text()[-3000:]
        time.sleep(0.5)
    time.sleep(2.0)
    tree = descendants(benchmark.pid)
    benchmark.send_signal(stop)
    assert benchmark.wait(timeout=60) == 1, log.read_text()[-3000:]
    left = wait_until_gone(tree, 30.0)
    for pid in left:  # clean up what a failing run left
        subprocess.run(["kill", "-KILL", str(pid)], check=False)
    assert not left, log.read_text()[-3000:]
    assert "interrupted (re-run with the same --out to resume)" in log.read_text()
    assert "Traceback" not in log.read_text(), log.read_text()[-3000:]  # a stop is no crash: nothing printed as one
    assert leaked_shm_files(present_before) == set()
    done = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert [e["agent"] for e in done] == ["expert"]  # the expert's episode ran before the graph's was cut
