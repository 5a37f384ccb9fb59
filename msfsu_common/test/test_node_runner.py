"""run_node ends a node on SIGINT / SIGTERM within a fraction of a second, whatever rclpy's executor is doing: the
node process tears the node down in its main thread and exits 0 (rclpy's own signal handling can leave a node that
answers neither signal; node_runner.py says how)."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

PROBE = Path(__file__).with_name("node_runner_probe.py")
START_TIMEOUT_S = 60.0  # importing rclpy and creating a participant on a loaded 2-core machine
STOP_TIMEOUT_S = 10.0  # a stopped node exits in well under a second; the margin is for a loaded machine


def start_probe(mode: str, ignore_sigint: bool = False) -> subprocess.Popen:
    """The probe node, once its executor spins. `ignore_sigint`: started as a shell starts a background job."""
    preexec = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignore_sigint else None
    process = subprocess.Popen([sys.executable, str(PROBE), mode], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True, preexec_fn=preexec)
    deadline = time.monotonic() + START_TIMEOUT_S
    line = ""
    while "spinning" not in line:
        line = process.stdout.readline()
        assert line or process.poll() is None, "the probe ended before it spun"
        assert time.monotonic() < deadline, "the probe did not spin"
    return process


def finish(process: subprocess.Popen) -> tuple[int, str, float]:
    """Exit code, the rest of the output and the seconds it took to exit."""
    started = time.monotonic()
    try:
        output = process.communicate(timeout=STOP_TIMEOUT_S)[0]
    except subprocess.TimeoutExpired:
        process.kill()
        output = process.communicate()[0]
        pytest.fail(f"the node did not exit within {STOP_TIMEOUT_S:.0f} s:\n{output}")
    return process.returncode, output, time.monotonic() - started


def test_a_context_shut_down_without_waking_the_executor_still_ends_the_node():
    """What rclpy's signal thread can do: wake the executor before the shutdown, so the wait that follows sees
    nothing. A plain executor.spin() then waits for good; run_node's bounded waits notice the shutdown."""
    code, output, _ = finish(start_probe("quiet-shutdown"))
    assert code == 0, output
    assert "context shut down" in output and "destroyed" in output


@pytest.mark.parametrize("sig, ignore_sigint", [(signal.SIGINT, False), (signal.SIGTERM, False),
                                                (signal.SIGINT, True)], ids=["SIGINT", "SIGTERM", "SIGINT-ignored"])
def test_a_stop_signal_tears_the_node_down_and_exits_0(sig, ignore_sigint):
    """SIGINT-ignored: a shell starts background jobs with SIGINT ignored; `kill -INT` must stop the node anyway."""
    process = start_probe("spin", ignore_sigint)
    process.send_signal(sig)
    code, output, _ = finish(process)
    assert code == 0, output
    assert "destroyed" in output


def test_a_second_stop_signal_during_the_teardown_ends_the_process_at_once():
    process = start_probe("slow-teardown")
    process.send_signal(signal.SIGINT)
    assert "tearing down" in process.stdout.readline()
    process.send_signal(signal.SIGTERM)
    code, output, seconds = finish(process)
    assert code == -signal.SIGTERM, output
    assert "destroyed" not in output and seconds < STOP_TIMEOUT_S


def test_a_teardown_that_hangs_prints_where_it_waits():
    """A node that does not stop says where it waits (every thread's stack, on stderr) before the launcher escalates."""
    from msfsu_common.node_runner import STALL_REPORT_S

    process = start_probe("slow-teardown")
    process.send_signal(signal.SIGINT)
    assert "tearing down" in process.stdout.readline()
    time.sleep(STALL_REPORT_S + 1.5)
    process.send_signal(signal.SIGTERM)
    code, output, _ = finish(process)
    assert code == -signal.SIGTERM, output
    assert "Timeout" in output and "node_runner_probe.py" in output and "in destroy_node" in output, output
