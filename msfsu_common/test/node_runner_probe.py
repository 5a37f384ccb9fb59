"""A node run by `run_node`, for test_node_runner.py: `python node_runner_probe.py MODE`.

MODE `quiet-shutdown`: a second after spinning starts, another thread shuts the context down the way rclpy's
signal-handling thread does (rcl_shutdown only: no on_shutdown callback, nothing wakes the executor); the node
has no timer or subscription that would wake it either. MODE `spin`: spins until stopped. MODE `slow-teardown`:
its teardown takes 60 s once the node and its context are gone (so a kill then leaves no Fast DDS segment behind).
Prints `spinning` once the executor runs and `destroyed` when the node is torn down.
"""

import sys
import threading
import time

from msfsu_common.node_runner import run_node


def probe_node(mode: str):
    from rclpy.node import Node

    class Probe(Node):
        def __init__(self) -> None:
            super().__init__("node_runner_probe")
            self.started = self.create_timer(0.05, self.on_started)

        def on_started(self) -> None:
            self.destroy_timer(self.started)  # from now on nothing in the node wakes the executor
            print("spinning", flush=True)
            if mode == "quiet-shutdown":
                threading.Thread(target=self.shut_down_quietly, daemon=True).start()

        def shut_down_quietly(self) -> None:
            time.sleep(1.0)  # the executor is blocked in its wait by now
            self.context.handle.shutdown()
            print("context shut down", flush=True)

        def destroy_node(self) -> None:
            super().destroy_node()
            if mode == "slow-teardown":  # the slow part after the context is gone: a kill leaves no DDS segment
                self.context.try_shutdown()
                print("tearing down", flush=True)
                time.sleep(60.0)
            print("destroyed", flush=True)

    return Probe()


if __name__ == "__main__":
    sys.exit(run_node(lambda: probe_node(sys.argv[1]), []))
