"""msfsu-benchmark end to end: one short route, the expert in-process and the tiny network through the
node graph (route, perception, control as processes) in lockstep with the simulator, videos of the failed
episodes; then a resume."""

import json
import subprocess
import sys

import numpy as np

from msfsu_evaluation.video import read_video

COMMAND = [sys.executable, "-m", "msfsu_evaluation.closed_loop"]


def test_smoke_route_through_the_node_graph_then_resume(tmp_path, tiny_checkpoint):
    out = tmp_path / "bench"
    # random weights barely drive: end the episode after 3 s without progress instead of 20 s
    arguments = ["--checkpoint", f"tiny={tiny_checkpoint}", "--suite", "smoke", "--tasks", "straight",
                 "--blocked-s", "3", "--video", "failures", "--out", str(out)]
    run = subprocess.run(COMMAND + arguments, capture_output=True, text=True, timeout=400)
    assert run.returncode == 0, run.stderr[-3000:]
    episodes = {e["agent"]: e for e in map(json.loads, (out / "episodes.jsonl").read_text().splitlines())}
    assert set(episodes) == {"expert", "tiny"}
    assert episodes["expert"]["status"] == "success" and episodes["expert"]["route"] == "smoke/straight/train/00"
    network = episodes["tiny"]
    assert network["status"] in ("success", "blocked", "timeout", "collision", "off_road")
    # lockstep: the graph answered every frame it was sent within the control timeout
    assert network["steps"] >= 30 and network["unanswered_frames"] == 0
    trajectory = np.load(out / "trajectories" / "tiny" / "smoke__straight__train__00.npy")
    assert trajectory.shape == (network["steps"] + 1, 6)
    report = json.loads((out / "results.json").read_text())
    cell = report["results"]["expert"]["smoke"]["straight"]["train"]
    assert cell["success_rate"] == 1.0 and cell["episodes"] == 1
    assert "| straight | 100 |" in (out / "results.md").read_text()
    assert (out / report["figures"][0]).stat().st_size > 10_000
    # --video failures: the successful expert episode leaves no video, a failed one a frame per simulator frame
    videos = out / "videos"
    assert not (videos / "expert").exists() or not list((videos / "expert").iterdir())
    if network["status"] != "success":
        meta, frames = read_video(videos / "tiny" / "smoke__straight__train__00.mp4")
        assert meta["codec"] == "h264" and len(frames) == network["steps"] + 1
        assert "1 episode videos" in run.stdout

    again = subprocess.run(COMMAND + arguments, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "0 episodes to run (2 done before)" in again.stderr
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 2


def test_usage_errors_exit_with_code_2(tmp_path):
    missing = subprocess.run(COMMAND + ["--checkpoint", str(tmp_path / "none.pt"), "--out", str(tmp_path / "o")],
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "does not exist" in missing.stderr
    neither = subprocess.run(COMMAND + ["--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
    assert neither.returncode == 2 and "--agent expert" in neither.stderr
