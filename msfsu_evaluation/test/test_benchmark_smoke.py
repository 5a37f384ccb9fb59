"""msfsu-benchmark end to end: one short route, the expert in-process and a tiny network through the
node graph (route, perception, control as processes) in lockstep with the simulator, a video of each
episode; then a resume.

The smoke route `smoke/straight/train/00` is 45 m of straight road with no junction, so a network that
always asks for steer 0 and a constant speed reaches its goal: the network here is the tiny MSFSU with
its policy head set to exactly that, and it must arrive like the expert, through the whole graph.
"""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from msfsu_evaluation.video import read_video

COMMAND = [sys.executable, "-m", "msfsu_evaluation.closed_loop"]
CRUISE_MPS = 5.0
STEP_S = 0.1  # the simulator's 10 Hz: one frame and one VehicleControl per step
GOAL_M = 5.0  # rules.EpisodeRules.goal_m


@pytest.fixture
def cruise_checkpoint(constant_policy_checkpoint):
    """The tiny network, its every branch answering steer 0 and CRUISE_MPS whatever it sees."""
    return constant_policy_checkpoint(0.0, CRUISE_MPS)


def assert_arrived(episode: dict) -> None:
    assert episode["status"] == "success" and episode["success"] and episode["collision_type"] == ""
    assert episode["route_completion"] == 1.0 and episode["distance_to_goal_m"] <= GOAL_M
    assert episode["time_s"] < episode["timeout_s"] and episode["unanswered_frames"] == 0
    assert episode["time_s"] == pytest.approx(episode["steps"] * STEP_S)


def test_smoke_route_through_the_node_graph_then_resume(tmp_path, cruise_checkpoint):
    out = tmp_path / "bench"
    # a graph that stops driving ends after 3 s without progress instead of 20 s
    # the network on a backend and precision of its own: the perception node is started with them
    # the network alone: the product's brake would judge the random segmentation (tests/test_aeb_closed_loop.py drives it)
    arguments = ["--checkpoint", f"cruise={cruise_checkpoint}", "--network-only", "cruise",
                 "--backend", "cruise=torch", "--precision", "fp32",
                 "--suite", "smoke", "--tasks", "straight", "--blocked-s", "3", "--video", "all", "--out", str(out)]
    run = subprocess.run(COMMAND + arguments, capture_output=True, text=True, timeout=400)
    assert run.returncode == 0, run.stderr[-3000:]
    info = json.loads((out / "run.json").read_text())
    assert info["agent_runtimes"] == {"cruise": {"backend": "torch", "precision": "fp32"}}  # no brake
    assert info["legs"][0]["runtimes"] == {"cruise": "cpu torch/fp32"}
    speed = info["legs"][0]["throughput"]["cruise"]  # the leg's throughput, where a step's time went
    assert speed["episodes"] == 1 and speed["steps"] > 0 and speed["timed_steps"] == speed["steps"]
    assert {"simulate", "publish", "wait for control"} <= set(speed["stage_ms_per_step"])
    assert {"worker", "perception", "control", "route"} <= set(speed["cpu_ms_per_step"])
    assert info["legs"][0]["episodes_per_hour"] > 0 and "throughput: cruise" in run.stderr
    (graph_log,) = (out / "logs").glob("cruise_domain*.log")
    assert "cpu torch/fp32, warm-up inference" in graph_log.read_text()  # what the node itself reports it runs
    assert "Networks' inference (asked -> ran as): cruise: torch/fp32 -> cpu torch/fp32." in (out / "results.md").read_text()
    episodes = {e["agent"]: e for e in map(json.loads, (out / "episodes.jsonl").read_text().splitlines())}
    assert set(episodes) == {"expert", "cruise"}
    assert {e["route"] for e in episodes.values()} == {"smoke/straight/train/00"}
    expert, network = episodes["expert"], episodes["cruise"]
    assert (expert["worker"], expert["worker_episode"], network["worker_episode"]) == (network["worker"], 0, 1)
    assert_arrived(expert)
    # the graph drove the route to its goal; lockstep: it answered every frame within the control timeout (each
    # frame it did not answer is named on stderr, with the load: kept in the message for the next such failure)
    assert network["unanswered_frames"] == 0, run.stderr[-3000:]
    assert_arrived(network)
    for episode in episodes.values():  # each crossing's start is recorded with its command and place
        assert len(episode["solid_lines"]) == episode["solid_line_crossings"]
        assert set(episode["metres_by_command"]) == {"LANE_FOLLOW"}  # 45 m to within the goal distance, no junction
        assert 45 - 2 * GOAL_M < episode["metres_by_command"]["LANE_FOLLOW"] == episode["metres_by_place"]["lane_follow"]
    trajectories = {agent: np.load(out / "trajectories" / agent / "smoke__straight__train__00.npy")
                    for agent in episodes}
    trajectory = trajectories["cruise"]
    assert trajectory.shape == (network["steps"] + 1, 6)
    assert np.allclose(np.diff(trajectory[:, 0]), STEP_S)  # one simulator step per answered frame
    assert np.array_equal(trajectory[0, :4], trajectories["expert"][0, :4])  # same spawn pose as the expert
    # the control node's PID brought the car to the network's target speed (last second within 10 %)
    assert abs(trajectory[-10:, 5].mean() - CRUISE_MPS) < 0.1 * CRUISE_MPS
    assert np.abs(trajectory[:, 4]).max() < 0.05  # steer 0: it never turned (yaw rate, rad/s)
    report = json.loads((out / "results.json").read_text())
    for agent in episodes:
        cell = report["results"][agent]["smoke"]["straight"]["train"]
        assert cell["success_rate"] == 1.0 and cell["episodes"] == 1
    assert "| straight | 1/1 (100; 21-100) | 1/1 (100; 21-100) |" in (out / "results.md").read_text()
    assert (out / report["figures"][0]).stat().st_size > 10_000
    # --video all: an H.264 video of each episode, a frame per simulator frame
    for agent, episode in episodes.items():
        meta, frames = read_video(out / "videos" / agent / "smoke__straight__train__00.mp4")
        assert meta["codec"] == "h264" and len(frames) == episode["steps"] + 1
    assert "2 episode videos" in run.stdout

    again = subprocess.run(COMMAND + arguments, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "2 episodes, 0 to run (2 done before)" in again.stderr
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 2
    # the same agent name on another precision would take the fp32 episodes as its own: refused
    other = [item.replace("fp32", "int8") for item in arguments]
    refused = subprocess.run(COMMAND + other, capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "run on backend torch, precision fp32, not torch/int8" in refused.stderr


@pytest.mark.slow  # 40 s; the default suite covers the pacing in the bridge node (msfsu_sim/test/test_bridge_node.py)
def test_smoke_route_free_running(tmp_path, cruise_checkpoint):
    """--real-time-factor: the simulator steps on the wall clock with the last control; the network still arrives,
    and the episode records the factor achieved and the age of every control it applied."""
    out = tmp_path / "free"
    arguments = ["--checkpoint", f"cruise={cruise_checkpoint}", "--suite", "smoke", "--tasks", "straight",
                 "--real-time-factor", "1", "--blocked-s", "3", "--out", str(out)]
    run = subprocess.run(COMMAND + arguments, capture_output=True, text=True, timeout=400)
    assert run.returncode == 0, run.stderr[-3000:]
    (episode,) = map(json.loads, (out / "episodes.jsonl").read_text().splitlines())  # no expert: it runs in lockstep
    assert episode["agent"] == "cruise" and episode["success"]
    free = episode["free_running"]
    assert free["real_time_factor"] == 1.0 and free["steps"] == episode["steps"]
    assert 0.5 <= free["achieved_real_time_factor"] <= 1.05
    ages = {int(age): count for age, count in free["control_age_steps"].items()}
    assert sum(ages.values()) + free["steps_without_control"] == free["steps"]
    assert ages.get(0, 0) >= 0.8 * free["steps"]  # the graph (~20 ms) answers most frames within the 100 ms period
    assert json.loads((out / "run.json").read_text())["real_time_factor"] == 1.0
    assert "## Free-running" in (out / "results.md").read_text()
    lockstep = subprocess.run(COMMAND + arguments[:6] + ["--out", str(out)], capture_output=True, text=True, timeout=60)
    assert lockstep.returncode == 2 and "real-time factor 1.0" in lockstep.stderr  # never mixed in one directory


def test_usage_errors_exit_with_code_2(tmp_path):
    missing = subprocess.run(COMMAND + ["--checkpoint", str(tmp_path / "none.pt"), "--out", str(tmp_path / "o")],
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "does not exist" in missing.stderr
    neither = subprocess.run(COMMAND + ["--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
    assert neither.returncode == 2 and "--agent expert" in neither.stderr


def test_backend_and_precision_per_network_agent(tmp_path):
    """`--precision [NAME=]VALUE`: a bare value sets every network, a named one overrides it for that agent; values
    and names are checked before anything runs."""
    from msfsu_evaluation.closed_loop.cli import build_parser, parse_agents
    from msfsu_evaluation.usage import UsageError

    a, b = tmp_path / "a.pt", tmp_path / "b.pt"
    a.write_bytes(b"a"), b.write_bytes(b"b")

    def agents(*extra: str) -> dict[str, tuple[str, str]]:
        options = build_parser().parse_args(["--checkpoint", f"a={a}", "--checkpoint", f"b={b}", "--out", "x", *extra])
        return {agent.name: (agent.backend, agent.precision) for agent in parse_agents(options)}

    assert agents() == {"expert": ("auto", "auto"), "a": ("auto", "auto"), "b": ("auto", "auto")}
    assert agents("--no-expert") == {"a": ("auto", "auto"), "b": ("auto", "auto")}  # its records are another run's
    with pytest.raises(UsageError, match="exclude each other"):
        parse_agents(build_parser().parse_args(["--agent", "expert", "--no-expert", "--out", "x"]))
    assert agents("--precision", "b=int8", "--precision", "fp32", "--backend", "a=torch") == {
        "expert": ("auto", "auto"), "a": ("torch", "fp32"), "b": ("auto", "int8")}
    for extra, message in ((["--precision", "fp8"], "'fp8' is none of auto, fp32, fp16, bf16, int8"),
                           (["--backend", "c=torch"], "'c' is no network agent of this run (a, b)"),
                           (["--backend", "expert=torch"], "'expert' is no network agent")):
        with pytest.raises(UsageError, match=re.escape(message)):
            agents(*extra)


def test_every_network_drives_as_the_product_unless_named_network_only(tmp_path):
    """A --checkpoint agent drives with the product's brake (msfsu_bringup/product.yaml: on, predicting crossings, the
    node's defaults) and precision rule; `--network-only NAME...` drives those networks alone. What each agent drove
    with is recorded per agent (its name says nothing)."""
    from msfsu_evaluation.closed_loop.cli import agent_runtimes, build_parser, parse_agents
    from msfsu_evaluation.usage import UsageError

    a = tmp_path / "a.pt"
    a.write_bytes(b"a")

    def agents(*extra: str):
        options = build_parser().parse_args(["--checkpoint", f"m={a}", "--checkpoint", f"alone={a}", "--no-expert",
                                             "--out", "x", *extra])
        return parse_agents(options)

    driven = {agent.name: (agent.aeb, agent.aeb_crossing) for agent in agents("--network-only", "alone")}
    assert driven == {"m": (True, True), "alone": (False, False)}
    runtimes = agent_runtimes(agents("--network-only", "alone"))
    assert runtimes["m"] == {"backend": "auto", "precision": "auto", "aeb": True, "aeb_crossing": True}
    assert runtimes["alone"] == {"backend": "auto", "precision": "auto"}
    assert {agent.aeb for agent in agents()} == {True}
    with pytest.raises(UsageError, match="--network-only b: no network agent of that name"):
        agents("--network-only", "b")


def test_a_brake_parameter_per_agent_is_checked_recorded_and_given_to_its_aeb_node(tmp_path):
    """`--aeb-param NAME:PARAMETER=VALUE` sets one of a braking agent's brake parameters beyond the product's (two
    brakes of one network that differ in a parameter drive in one run, paired); the value is checked as the node checks
    it, recorded with the agent's runtime (so a run directory cannot be resumed with another value), and the agent
    profile hands it to the aeb node's parameters."""
    from msfsu_bringup.launcher import load_profile, profile_path
    from msfsu_evaluation.closed_loop.cli import agent_runtimes, build_parser, parse_agents
    from msfsu_evaluation.closed_loop.markdown import runtimes_markdown
    from msfsu_evaluation.usage import UsageError

    a = tmp_path / "a.pt"
    a.write_bytes(b"a")

    def agents(*extra: str):
        options = build_parser().parse_args(["--checkpoint", f"m_aeb={a}", "--checkpoint", f"m_aeb_l={a}",
                                             "--checkpoint", f"m={a}", "--network-only", "m", "--no-expert", "--out",
                                             "x", *extra])
        return {agent.name: agent for agent in parse_agents(options)}

    chosen = agents("--aeb-param", "m_aeb_l:track_lost_s=0.5", "--aeb-param", "m_aeb_l:min_pixels=6")
    assert chosen["m_aeb"].aeb_parameters == ()
    assert chosen["m_aeb_l"].aeb_parameters == (("min_pixels", 6), ("track_lost_s", 0.5))
    runtimes = agent_runtimes(list(chosen.values()))
    assert "aeb_parameters" not in runtimes["m_aeb"]
    assert runtimes["m_aeb_l"]["aeb_parameters"] == {"min_pixels": 6, "track_lost_s": 0.5}
    page = runtimes_markdown({name: {**runtime, "ran_as": ["cpu openvino/int8"]} for name, runtime in runtimes.items()})
    assert page[2] == ("Emergency brake parameters other than the aeb node's defaults: m_aeb_l: min_pixels 6, "
                       "track_lost_s 0.5.")
    assert len(runtimes_markdown({"m_aeb": {**runtimes["m_aeb"], "ran_as": []}})) == 2  # defaults: no such line
    corridor = agents("--aeb-param", "m_aeb_l:predict_crossing=false")["m_aeb_l"]  # the corridor-only brake
    assert (corridor.aeb, corridor.aeb_crossing, corridor.aeb_parameters) == (True, False, ())
    for item, message in (("m:track_lost_s=0.5", "'m' drives without the brake"),
                          ("m_aeb_l:track_lost=0.5", "no such parameter: track_lost"),
                          ("m_aeb_l:track_lost_s=9", "track_lost_s 9.0 is outside [0.0, 5.0]"),
                          ("m_aeb_l:min_pixels=2.5", "min_pixels takes a int, not float"),
                          ("m_aeb_l=track_lost_s", "give NAME:PARAMETER=VALUE")):
        with pytest.raises(UsageError, match=re.escape(message)):
            agents("--aeb-param", item)

    _, nodes = load_profile(profile_path("agent"), {"checkpoint": str(a), "aeb_parameters": '{"track_lost_s": 0.5}'})
    aeb = next(node for node in nodes if node.name == "aeb")
    assert aeb.parameters["track_lost_s"] == 0.5 and "predict_crossing" not in aeb.parameters  # the node's default:
    from msfsu_control.aeb import AebConfig

    assert AebConfig().predict_crossing is True
