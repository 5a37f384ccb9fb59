"""Wilson intervals, driving score, infractions per km, shards and merged reports on hand-made records."""

import json
from dataclasses import astuple, replace
from pathlib import Path

import numpy as np
import pytest

from msfsu_evaluation.closed_loop import report
from msfsu_evaluation.closed_loop.episode_record import AebInterventions, EpisodeResult
from msfsu_evaluation.closed_loop.paper import GOALS, PAPER_MSFSU_SUCCESS, against
from msfsu_evaluation.closed_loop.runner import EPISODES_FILE, RUN_FILE, Agent, Job, Shard, trajectory_path
from msfsu_evaluation.closed_loop.statistics import (
    cell_statistics, driving_score, mcnemar_exact_p, paired_comparison, paired_difference_interval, recorded_infractions,
    wilson_interval)
from msfsu_evaluation.closed_loop.suites import load_routes
from msfsu_evaluation.usage import UsageError


def test_wilson_interval_matches_the_textbook_values():
    interval = wilson_interval(8, 10)  # Wilson (1927) / Newcombe (1998) table: 0.490-0.943
    assert interval.low == pytest.approx(0.4902, abs=1e-4) and interval.high == pytest.approx(0.9433, abs=1e-4)
    assert wilson_interval(0, 25).low == 0.0 and wilson_interval(0, 25).high == pytest.approx(0.1332, abs=1e-4)
    assert wilson_interval(25, 25).high == 1.0 and wilson_interval(25, 25).low == pytest.approx(0.8668, abs=1e-4)
    assert wilson_interval(5, 10).overlaps(wilson_interval(9, 10))
    assert not wilson_interval(1, 25).overlaps(wilson_interval(24, 25))
    with pytest.raises(ValueError):
        wilson_interval(3, 2)


def test_driving_score_is_completion_times_the_leaderboard_penalty():
    assert driving_score(1.0, "") == 1.0
    assert driving_score(0.5, "pedestrian") == pytest.approx(0.25)
    assert driving_score(0.5, "vehicle") == pytest.approx(0.30)
    assert driving_score(1.0, "object") == pytest.approx(0.65)
    with pytest.raises(ValueError, match="unknown collision"):
        driving_score(1.0, "tree")


def episode(route: str, status: str, completion: float, collision: str = "", agent: str = "expert") -> EpisodeResult:
    return EpisodeResult(agent, route, status, status == "success", time_s=30.0, steps=300,
                         route_completion=completion, collision_type=collision, distance_to_goal_m=0.0,
                         timeout_s=60.0, wall_s=10.0, unanswered_frames=0, solid_line_crossings=0)


def test_cell_statistics_counts_infractions_per_km_driven():
    lengths = {"a": 200.0, "b": 400.0, "c": 100.0}
    stats = cell_statistics([episode("a", "success", 1.0), episode("b", "collision", 0.5, "vehicle"),
                             episode("c", "off_road", 0.0)], lengths, recorded_infractions(2))
    assert (stats.episodes, stats.successes) == (3, 1)
    assert stats.km_driven == pytest.approx(0.4)  # 200 m + 200 m + 0 m
    assert stats.infractions == {"pedestrian": 0, "vehicle": 1, "object": 0, "off_road": 1}  # what v2 recorded
    assert stats.infractions_per_km()["vehicle"] == pytest.approx(2.5)
    assert stats.driving_score == pytest.approx((1.0 + 0.5 * 0.6 + 0.0) / 3)
    assert stats.route_completion == pytest.approx(0.5)


def test_v3_records_count_static_layout_strikes_and_solid_line_crossings():
    lengths = {"a": 1000.0, "b": 1000.0}
    kerb = replace(episode("a", "collision", 0.5, "sidewalk"), solid_line_crossings=2)
    clean = replace(episode("b", "success", 1.0), solid_line_crossings=1)
    stats = cell_statistics([kerb, clean], lengths, recorded_infractions(3))
    assert stats.infractions == {"pedestrian": 0, "vehicle": 0, "object": 0, "static": 1, "off_road": 0,
                                 "solid_line": 3}
    assert stats.infractions_per_km()["solid_line"] == pytest.approx(3 / 1.5)
    assert stats.driving_score == pytest.approx((0.5 * 0.65 + 1.0) / 2)
    with pytest.raises(ValueError, match="static infraction"):  # a v2 page never shows a strike it did not record
        cell_statistics([kerb], lengths, recorded_infractions(2))
    with pytest.raises(ValueError, match="no solid_line_crossings"):  # a v3 page never counts what was not recorded
        cell_statistics([replace(clean, solid_line_crossings=None)], lengths, recorded_infractions(3))


def test_shards_are_disjoint_deterministic_and_cover_the_suite():
    _, routes = load_routes()
    jobs = [Job(Agent(name), route) for name in ("expert", "msfsu") for route in routes[:40]]
    shards = [Shard(k, 3).select(jobs) for k in (1, 2, 3)]
    assert sorted(len(s) for s in shards) == [26, 27, 27]
    keys = [(j.agent.name, j.route.key) for shard in shards for j in shard]
    assert len(keys) == len(set(keys)) == len(jobs)
    assert Shard(2, 3).select(list(reversed(jobs))) == shards[1]  # the order given does not matter
    assert str(Shard.parse("2/3")) == "2/3"
    for bad in ("0/3", "4/3", "2", "a/b"):
        with pytest.raises(ValueError):
            Shard.parse(bad)


def _write_run(run, episodes, version):
    run.mkdir(parents=True)
    (run / RUN_FILE).write_text(json.dumps({"routes_version": version, "routes_file": "routes.json"}))
    (run / EPISODES_FILE).write_text("".join(json.dumps(e.to_dict()) + "\n" for e in episodes))
    for e in episodes:
        path = trajectory_path(run, e.agent, e.route)
        path.parent.mkdir(parents=True, exist_ok=True)
        t = np.arange(0.0, 3.0, 0.1)
        offset = 0.0 if e.agent == "expert" else 0.5
        np.save(path, np.stack([t, t, t * 0 + offset, t * 0, t * 0, t * 0 + 1], axis=1).astype(np.float32))


def test_two_shards_merge_into_the_report_of_one_run(tmp_path):
    version, routes = load_routes()
    keys = [r.key for r in routes if r.suite == "corl2017" and r.task == "straight" and r.condition == "train"][:4]
    records = [episode(keys[0], "success", 1.0), episode(keys[1], "collision", 0.3, "pedestrian"),
               episode(keys[0], "success", 1.0, agent="net"), episode(keys[1], "success", 1.0, agent="net"),
               episode(keys[2], "success", 1.0), episode(keys[2], "timeout", 0.7, agent="net")]
    _write_run(tmp_path / "whole", records, version)
    _write_run(tmp_path / "s1", records[::2], version)
    _write_run(tmp_path / "s2", records[1::2], version)
    assert report.main([str(tmp_path / "whole"), "--out", str(tmp_path / "one")]) == 0
    assert report.main([str(tmp_path / "s1"), str(tmp_path / "s2"), "--out", str(tmp_path / "merged")]) == 0
    one, merged = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("one", "merged"))
    assert one["results"] == merged["results"]
    cell = merged["results"]["net"]["corl2017"]["straight"]["train"]
    assert (cell["episodes"], cell["successes"]) == (3, 2)
    assert cell["rmse_m"] == pytest.approx(0.5) and cell["rmse_episodes"] == 1  # only where the expert succeeded too
    expert = merged["results"]["expert"]["corl2017"]["straight"]["train"]
    assert expert["infractions"]["pedestrian"] == 1 and expert["driving_score"] == pytest.approx((2 + 0.15) / 3, abs=1e-4)
    markdown = (tmp_path / "merged" / "results.md").read_text()
    assert "| straight | 2/3 (67; 21-94) | 2/3 (67; 21-94) |" in markdown
    assert "| corl2017/straight | train | – |" not in markdown  # one network: no ablation table
    assert "6 episodes from" in markdown


def test_runs_of_different_route_versions_are_never_merged(tmp_path, capsys):
    version, routes = load_routes()
    _write_run(tmp_path / "a", [episode(routes[0].key, "success", 1.0)], version)
    _write_run(tmp_path / "b", [episode(routes[0].key, "success", 1.0)], version - 1)
    assert report.main([str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "o")]) == 2
    assert "never mixed" in capsys.readouterr().err
    assert report.main([str(tmp_path / "nothing"), "--out", str(tmp_path / "o")]) == 2


def test_runs_of_different_simulator_revisions_are_never_merged_nor_resumed(tmp_path, capsys):
    """Runs before revision 2 (no simulator_revision in run.json) kept Bullet worlds across episodes."""
    from msfsu_evaluation.closed_loop.cli import _check_run_dir
    from msfsu_sim import SIMULATOR_REVISION

    version, routes = load_routes()
    _write_run(tmp_path / "old", [episode(routes[0].key, "success", 1.0)], version)  # revision 1 by absence
    _write_run(tmp_path / "new", [episode(routes[1].key, "success", 1.0)], version)
    info = json.loads((tmp_path / "new" / RUN_FILE).read_text())
    (tmp_path / "new" / RUN_FILE).write_text(json.dumps({**info, "simulator_revision": SIMULATOR_REVISION}))
    assert report.main([str(tmp_path / "old"), str(tmp_path / "new"), "--out", str(tmp_path / "o")]) == 2
    assert f"different simulator revisions [1, {SIMULATOR_REVISION}]: never mixed" in capsys.readouterr().err
    assert report.main([str(tmp_path / "new"), "--out", str(tmp_path / "o")]) == 0
    assert json.loads((tmp_path / "o" / "results.json").read_text())["run"]["simulator_revision"] == SIMULATOR_REVISION
    resume = {"routes_version": version, "routes_file": "routes.json", "shard": "1/1", "real_time_factor": None,
              "simulator_revision": SIMULATOR_REVISION, "agents": {"expert": None}, "checkpoint_digests": {}}
    with pytest.raises(UsageError, match=f"simulator revision 1, this code is revision {SIMULATOR_REVISION}"):
        _check_run_dir(tmp_path / "old", resume)
    _check_run_dir(tmp_path / "new", resume)


def test_networks_driven_through_different_graph_revisions_are_never_merged_nor_resumed(tmp_path, capsys):
    """A network's lockstep episodes changed with the node graph (msfsu_bringup.GRAPH_REVISION): runs whose networks
    drove through different revisions are never merged nor resumed. The expert drives without the graph."""
    from msfsu_bringup import GRAPH_REVISION
    from msfsu_evaluation.closed_loop.cli import _check_run_dir
    from msfsu_sim import SIMULATOR_REVISION

    version, routes = load_routes()

    def write(name: str, agent: str, graph: int | None = None) -> Path:
        _write_run(tmp_path / name, [episode(routes[0].key, "success", 1.0, agent=agent)], version)
        info = {"routes_version": version, "routes_file": "routes.json", "simulator_revision": SIMULATOR_REVISION,
                "agents": {agent: None if agent == "expert" else "models/a.pt"}}
        (tmp_path / name / RUN_FILE).write_text(json.dumps(info if graph is None else {**info, "graph_revision": graph}))
        return tmp_path / name

    old, new, expert = write("old", "net"), write("new", "net", GRAPH_REVISION), write("expert", "expert")  # old: 1
    assert report.main([str(old), str(new), "--out", str(tmp_path / "o")]) == 2
    assert f"different node graph revisions [1, {GRAPH_REVISION}]: never mixed" in capsys.readouterr().err
    assert report.main([str(new), str(expert), "--out", str(tmp_path / "o")]) == 0
    assert json.loads((tmp_path / "o" / "results.json").read_text())["run"]["graph_revision"] == GRAPH_REVISION
    assert report.main([str(expert), "--out", str(tmp_path / "e")]) == 0  # no network, no graph
    assert "graph_revision" not in json.loads((tmp_path / "e" / "results.json").read_text())["run"]
    resume = {"routes_version": version, "routes_file": "routes.json", "shard": "1/1", "real_time_factor": None,
              "simulator_revision": SIMULATOR_REVISION, "graph_revision": GRAPH_REVISION,
              "agents": {"expert": None}, "checkpoint_digests": {}}
    with pytest.raises(UsageError, match=f"holds networks driven through node graph revision 1, this code is "
                                         f"revision {GRAPH_REVISION}"):
        _check_run_dir(old, resume)  # not even the expert joins it: run.json would then name the new revision
    _check_run_dir(new, resume)
    _check_run_dir(expert, {**resume, "agents": {"msfsu": "models/a.pt"}, "checkpoint_digests": {"msfsu": "aaaa"}})
    assert json.loads((expert / RUN_FILE).read_text())["graph_revision"] == GRAPH_REVISION


def test_a_run_resumes_an_agent_only_with_the_checkpoint_it_started_with(tmp_path):
    """Agent names stay (msfsu, round0 ...) while the models behind them are retrained: a run directory that holds
    an agent's episodes takes that name only with the same checkpoint content, else its episodes would count as done."""
    from msfsu_evaluation.closed_loop.cli import _check_run_dir
    from msfsu_sim import SIMULATOR_REVISION

    version, _ = load_routes()
    base = {"routes_version": version, "routes_file": "routes.json", "shard": "1/1", "real_time_factor": None,
            "simulator_revision": SIMULATOR_REVISION}
    run = tmp_path / "run"
    _check_run_dir(run, {**base, "agents": {"msfsu": "models/a.pt"}, "checkpoint_digests": {"msfsu": "aaaa"}})
    _check_run_dir(run, {**base, "agents": {"msfsu": "models/a.pt"}, "checkpoint_digests": {"msfsu": "aaaa"}})
    with pytest.raises(UsageError, match="holds agent 'msfsu' run with another checkpoint .models/a.pt., not "
                                         "models/a.pt as it is now"):
        _check_run_dir(run, {**base, "agents": {"msfsu": "models/a.pt"}, "checkpoint_digests": {"msfsu": "bbbb"}})
    _check_run_dir(run, {**base, "agents": {"msf": "models/b.pt"}, "checkpoint_digests": {"msf": "bbbb"}})  # new name
    assert json.loads((run / RUN_FILE).read_text())["checkpoint_digests"] == {"msfsu": "aaaa", "msf": "bbbb"}
    # a run from before digests were recorded cannot say which model it ran: a network agent is refused
    (run / RUN_FILE).write_text(json.dumps({**base, "agents": {"expert": None, "msfsu": "models/a.pt"}}))
    with pytest.raises(UsageError, match="a checkpoint whose content it did not record"):
        _check_run_dir(run, {**base, "agents": {"msfsu": "models/a.pt"}, "checkpoint_digests": {"msfsu": "aaaa"}})
    _check_run_dir(run, {**base, "agents": {"expert": None}, "checkpoint_digests": {}})  # the expert has no checkpoint


def test_a_run_resumes_an_agent_only_on_the_backend_and_precision_it_started_with(tmp_path):
    """An int8 and an fp32 drive of one checkpoint are two agents: a run directory takes an agent name only with the
    backend and precision its episodes were driven on (a run.json that recorded none drove on auto/auto)."""
    from msfsu_evaluation.closed_loop.cli import _check_run_dir
    from msfsu_sim import SIMULATOR_REVISION

    version, _ = load_routes()
    base = {"routes_version": version, "routes_file": "routes.json", "shard": "1/1", "real_time_factor": None,
            "simulator_revision": SIMULATOR_REVISION, "checkpoint_digests": {"msfsu": "aaaa"}}
    auto = {"backend": "auto", "precision": "auto"}
    run = tmp_path / "run"
    (run).mkdir()
    (run / RUN_FILE).write_text(json.dumps({**base, "agents": {"msfsu": "models/a.pt"}}))  # recorded no runtime
    _check_run_dir(run, {**base, "agents": {"msfsu": "models/a.pt"}, "agent_runtimes": {"msfsu": auto}})
    fp32 = {"backend": "auto", "precision": "fp32"}
    with pytest.raises(UsageError, match="holds agent 'msfsu' run on backend auto, precision auto, not auto/fp32"):
        _check_run_dir(run, {**base, "agents": {"msfsu": "models/a.pt"}, "agent_runtimes": {"msfsu": fp32}})
    _check_run_dir(run, {**base, "checkpoint_digests": {"msfsu_fp32": "aaaa"}, "agents": {"msfsu_fp32": "models/a.pt"},
                         "agent_runtimes": {"msfsu_fp32": fp32}})  # under a name of its own
    assert json.loads((run / RUN_FILE).read_text())["agent_runtimes"] == {"msfsu": auto, "msfsu_fp32": fp32}


def test_a_run_records_every_machine_it_ran_on_and_says_so_when_a_network_resumes_on_another(tmp_path, capsys):
    """A network's episodes differ between CPUs (msfsu_common.machine): a run directory lists the machines that
    ran it, and resuming a network agent on a new one says that its episodes then come from two machines."""
    from datetime import datetime, timedelta, timezone

    from msfsu_common.machine import cpu_model, describe_cpu, utc_stamp
    from msfsu_evaluation.closed_loop.cli import _check_run_dir
    from msfsu_sim import SIMULATOR_REVISION

    version, _ = load_routes()
    base = {"routes_version": version, "routes_file": "routes.json", "shard": "1/1", "real_time_factor": None,
            "simulator_revision": SIMULATOR_REVISION, "agents": {"msfsu": "models/a.pt"},
            "checkpoint_digests": {"msfsu": "aaaa"}}
    run = tmp_path / "run"
    _check_run_dir(run, {**base, "machines": ["CPU A, 2 CPUs, avx2"]})
    _check_run_dir(run, {**base, "machines": ["CPU A, 2 CPUs, avx2"]})
    assert capsys.readouterr().err == ""
    _check_run_dir(run, {**base, "machines": ["CPU B, 16 CPUs, avx2 avx512f"]})
    assert "was run on CPU A, 2 CPUs, avx2, this is CPU B, 16 CPUs, avx2 avx512f" in capsys.readouterr().err
    assert json.loads((run / RUN_FILE).read_text())["machines"] == ["CPU A, 2 CPUs, avx2", "CPU B, 16 CPUs, avx2 avx512f"]
    from msfsu_evaluation.closed_loop.cli import _now, _record_leg

    _record_leg(run, {"started": _now(), "workers": 2, "agents": ["msfsu"], "to_run": 3, "finished": 3}, [])
    _check_run_dir(run, {**base, "machines": ["CPU B, 16 CPUs, avx2 avx512f"]})  # a resume keeps the legs
    (leg,) = json.loads((run / RUN_FILE).read_text())["legs"]
    assert leg["workers"] == 2 and leg["finished"] == 3 and 0 <= leg["wall_s"] < 60 and "load_1min_end" in leg
    cpuinfo = "processor\t: 0\nmodel name\t: Some CPU\nflags\t\t: fpu sse avx2 fma avx512f avx512_vnni\n"
    assert describe_cpu(cpuinfo).startswith("Some CPU, ") and describe_cpu(cpuinfo).endswith(", avx2 fma avx512f avx512_vnni")
    assert cpu_model(cpuinfo) == ("Some CPU", "avx2 fma avx512f avx512_vnni")  # benchmarks/training.py's machine
    assert cpu_model("processor\t: 0\n")[1] == "no listed flags"
    # when a benchmark record was measured: one form for every record, in UTC whatever the zone given
    assert utc_stamp(datetime(2026, 11, 28, 16, 5, tzinfo=timezone(timedelta(hours=2)))) == "2026-11-28 14:05 UTC"
    assert datetime.strptime(utc_stamp(), "%Y-%m-%d %H:%M UTC")


def test_two_runs_of_one_agent_on_one_route_are_refused_unless_one_is_preferred(tmp_path, capsys):
    version, routes = load_routes()
    keys = [r.key for r in routes if r.suite == "corl2017" and r.task == "straight" and r.condition == "train"][:3]
    _write_run(tmp_path / "expert_run", [episode(keys[0], "success", 1.0), episode(keys[1], "success", 1.0)], version)
    _write_run(tmp_path / "networks_run", [episode(keys[1], "timeout", 0.4), episode(keys[2], "success", 1.0),
                                           episode(keys[1], "success", 1.0, agent="net")], version)
    runs = [str(tmp_path / "expert_run"), str(tmp_path / "networks_run")]
    assert report.main([*runs, "--out", str(tmp_path / "o")]) == 2
    error = capsys.readouterr().err
    assert f"expert drove {keys[1]} in both" in error and "--prefer expert=RUN" in error
    # the expert stays in as every network's RMSE reference, so its overlap must be settled for one network too
    assert report.main([*runs, "--agents", "net", "--out", str(tmp_path / "net")]) == 2
    assert report.main([*runs, "--prefer", f"expert={tmp_path / 'elsewhere'}", "--out", str(tmp_path / "o")]) == 2
    for preferred, outcome in (("expert_run", 1), ("networks_run", 0)):
        out = tmp_path / preferred
        assert report.main([*runs, "--prefer", f"expert={tmp_path / preferred}", "--out", str(out)]) == 0
        results = json.loads((out / "results.json").read_text())
        cell = results["results"]["expert"]["corl2017"]["straight"]["train"]
        assert (cell["episodes"], cell["successes"]) == (3, 2 + outcome)  # keys[0] and keys[2] either way
        assert results["prefer"] == {"expert": str(tmp_path / preferred)}
        assert sum(results["sources"]["expert"].values()) == 3 and results["sources"]["net"] == {runs[1]: 1}
        assert f"(where both hold a route, `{tmp_path / preferred}` wins)" in (out / "results.md").read_text()
        # the report says how the runs agree where they overlap (a deterministic simulator repeats every record)
        assert results["overlap"] == {"expert": {"routes": 1, "identical": 0, "same_outcome": 0, "differ": [keys[1]]}}
        assert f"not identical: {keys[1]}." in (out / "results.md").read_text()
    _write_run(tmp_path / "again", [episode(keys[0], "success", 1.0), episode(keys[1], "success", 1.0)], version)
    both = [runs[0], str(tmp_path / "again")]
    assert report.main([*both, "--prefer", f"expert={runs[0]}", "--out", str(tmp_path / "same")]) == 0
    overlap = json.loads((tmp_path / "same" / "results.json").read_text())["overlap"]
    assert overlap == {"expert": {"routes": 2, "identical": 2, "same_outcome": 2, "differ": []}}


def test_exact_mcnemar_p_is_the_two_sided_binomial_tail_of_the_discordant_routes():
    assert mcnemar_exact_p(1, 9) == pytest.approx(2 * (1 + 10) / 2 ** 10)  # 0.0215
    assert mcnemar_exact_p(9, 1) == mcnemar_exact_p(1, 9)
    assert mcnemar_exact_p(0, 5) == pytest.approx(2 / 32)
    assert mcnemar_exact_p(3, 3) == 1.0 and mcnemar_exact_p(0, 0) == 1.0
    with pytest.raises(ValueError):
        mcnemar_exact_p(-1, 2)


def test_paired_interval_holds_the_estimate_mirrors_and_stays_in_range():
    for counts in [(40, 10, 2, 18), (0, 0, 0, 7), (5, 0, 7, 0), (70, 0, 0, 0), (0, 3, 0, 0), (12, 9, 2, 21)]:
        both, only_a, only_b, neither = counts
        n = sum(counts)
        interval = paired_difference_interval(*counts)
        mirrored = paired_difference_interval(both, only_b, only_a, neither)
        assert -1.0 <= interval.low <= (only_a - only_b) / n <= interval.high <= 1.0
        assert mirrored.low == pytest.approx(-interval.high) and mirrored.high == pytest.approx(-interval.low)
    with pytest.raises(ValueError):
        paired_difference_interval(0, 0, 0, 0)


def test_paired_interval_covers_the_true_difference_about_95_percent_of_the_time():
    # 70 routes (a condition of the benchmark at 10 per cell); a succeeds on 80 %, b on 65 %, correlated.
    rng = np.random.default_rng(7)
    probabilities = np.array([0.6, 0.2, 0.05, 0.15])  # both, only a, only b, neither
    true_difference = probabilities[1] - probabilities[2]
    draws = rng.multinomial(70, probabilities, size=2000)
    covered = [(i := paired_difference_interval(*map(int, d))).low <= true_difference <= i.high for d in draws]
    assert 0.93 <= np.mean(covered) <= 0.98  # Newcombe reports ~95 % for method 10


def test_paired_comparison_uses_only_the_routes_both_agents_drove():
    a = {"r1": True, "r2": True, "r3": False, "r4": True, "only_in_a": True}
    b = {"r1": True, "r2": False, "r3": False, "r4": False, "only_in_b": False}
    comparison = paired_comparison(a, b)
    assert (comparison.routes, comparison.a_successes, comparison.b_successes) == (4, 3, 1)
    assert (comparison.only_a, comparison.only_b) == (2, 0)
    assert comparison.difference == pytest.approx(0.5) and comparison.p_value == pytest.approx(0.5)
    assert paired_comparison({"x": True}, {"y": True}) is None


def test_report_compares_two_networks_route_by_route(tmp_path):
    version, routes = load_routes()
    train = [r.key for r in routes if r.suite == "corl2017" and r.task == "navigation" and r.condition == "train"][:10]
    heldout = [r.key for r in routes if r.suite == "nocrash" and r.task == "nocrash_dense" and r.condition == "heldout"]
    records = [episode(key, "success", 1.0, agent="good") for key in train]
    records += [episode(key, "success" if i < 2 else "collision", 0.5 if i >= 2 else 1.0,
                        "" if i < 2 else "vehicle", agent="bad") for i, key in enumerate(train)]
    records += [episode(heldout[0], "success", 1.0, agent="good"), episode(heldout[1], "success", 1.0, agent="bad")]
    _write_run(tmp_path / "run", records, version)
    assert report.main([str(tmp_path / "run"), "--out", str(tmp_path / "out")]) == 0
    rows = {(r["suite"], r["condition"]): r for r in json.loads((tmp_path / "out" / "results.json").read_text())["paired"]}
    corl = rows[("corl2017", "train")]
    assert (corl["a"], corl["b"], corl["routes"], corl["only_a"], corl["only_b"]) == ("bad", "good", 10, 0, 8)
    assert corl["difference"] == pytest.approx(-0.8) and corl["mcnemar_p"] == pytest.approx(2 / 2 ** 8, abs=1e-4)
    assert corl["difference_ci95"][1] < 0  # separated: 8 of 8 discordant routes favour "good"
    assert ("nocrash", "heldout") not in rows  # no route both drove
    assert rows[("all", "train")]["routes"] == 10
    markdown = (tmp_path / "out" / "results.md").read_text()
    assert "| bad vs good | corl2017 | train | 10 | 2 | 10 | 0 | 8 | -80 (" in markdown


def test_a_cell_is_measured_against_the_papers_rate_and_the_v3_goal():
    dense = ("nocrash", "nocrash_dense", "heldout")  # paper 43 %, goal 43 %
    measured = against(dense, 8, 25, *astuple(wilson_interval(8, 25)))  # 32 % (17-52)
    assert (measured.paper, measured.goal, measured.goal_met) == (43, 43, False)
    assert measured.versus_paper == "below, interval holds it"  # 25 routes cannot tell 32 % from 43 %
    assert against(dense, 2, 25, *astuple(wilson_interval(2, 25))).versus_paper == "below"  # 8 % (2-25)
    assert against(dense, 11, 25, *astuple(wilson_interval(11, 25))).goal_met  # 44 %
    one_turn = ("corl2017", "one_turn", "train")  # paper 100 %, goal 96 %: one failure in 25 allowed
    assert against(one_turn, 24, 25, *astuple(wilson_interval(24, 25))).goal_met
    assert not against(one_turn, 23, 25, *astuple(wilson_interval(23, 25))).goal_met
    empty = against(("nocrash", "nocrash_empty", "train"), 25, 25, 0.87, 1.0)
    assert (empty.goal, empty.goal_met, empty.versus_paper) == (None, None, "at or above")
    assert set(GOALS) <= set(PAPER_MSFSU_SUCCESS)


def test_report_measures_each_agent_against_the_paper(tmp_path):
    version, routes = load_routes()
    dense = [r for r in routes if r.task == "nocrash_dense" and r.condition == "heldout"][:10]
    records = [episode(r.key, "success" if i < 5 else "collision", 1.0 if i < 5 else 0.5,
                       "" if i < 5 else "pedestrian", agent="net") for i, r in enumerate(dense)]
    _write_run(tmp_path / "run", records, version)
    assert report.main([str(tmp_path / "run"), "--out", str(tmp_path / "out")]) == 0
    found = json.loads((tmp_path / "out" / "results.json").read_text())["against_paper"]["net"]
    cell = found["cells"]["nocrash/nocrash_dense/heldout"]
    assert (cell["success_rate"], cell["goal"], cell["goal_met"]) == (50, 43, True)
    assert list(found["cells"]) == ["nocrash/nocrash_dense/heldout"]  # only the cells it drove
    km = sum(r.length_m for r in dense[:5]) / 1000 + sum(r.length_m for r in dense[5:]) / 2000
    pedestrian = found["pedestrian_per_km_heldout"]
    assert pedestrian["collisions"] == 5 and pedestrian["per_km"] == pytest.approx(5 / km, abs=1e-3)
    assert pedestrian["goal_met"] is False
    markdown = (tmp_path / "out" / "results.md").read_text()
    assert "| nocrash/nocrash_dense | heldout | 43 | ≥ 43 | 50 (24-76); goal met; at or above |" in markdown
    assert "net: 1 of 1 success goals met; pedestrian collisions held out" in markdown


def test_report_counts_the_emergency_brakes_interventions_per_agent_and_condition(tmp_path):
    """The brake's brakes, caps and false ones summed per agent and condition, the false ones per 10 km driven; caps
    recorded before they were judged (false_caps None) make the false caps 'not judged'; no table without a brake."""
    version, routes = load_routes()
    length = {r.key: r.length_m for r in routes}
    train = [r.key for r in routes if r.suite == "corl2017" and r.task == "navigation" and r.condition == "train"][:2]
    heldout = [r.key for r in routes if r.task == "nocrash_dense" and r.condition == "heldout"][:1]

    def braked(key: str, completion: float, aeb: AebInterventions) -> EpisodeResult:
        return replace(episode(key, "success", completion, agent="net_aeb"), aeb=aeb)

    records = [braked(train[0], 1.0, AebInterventions(3, 2, 1, 1)), braked(train[1], 0.5, AebInterventions(1, 4, 0, 0)),
               braked(heldout[0], 1.0, AebInterventions(2, 1, 0, None)), episode(train[0], "success", 1.0, agent="net")]
    _write_run(tmp_path / "run", records, version)
    assert report.main([str(tmp_path / "run"), "--out", str(tmp_path / "out")]) == 0
    summary = json.loads((tmp_path / "out" / "results.json").read_text())["emergency_brake"]
    assert set(summary) == {"net_aeb"}  # the agent without a brake has no row
    km = (length[train[0]] + 0.5 * length[train[1]]) / 1000.0
    assert summary["net_aeb"]["train"] == {"episodes": 2, "km": round(km, 3), "brakes": 4, "caps": 6, "false_brakes": 1,
                                           "false_caps": 1, "false_per_10km": round(10.0 * 2 / km, 2)}
    assert summary["net_aeb"]["heldout"]["false_caps"] is None
    markdown = (tmp_path / "out" / "results.md").read_text()
    assert "## The emergency brake's interventions" in markdown
    assert f"| net_aeb | heldout | 1 | {length[heldout[0]] / 1000.0:.2f} | 2 | 1 | 0 | not judged | 0.00 |" in markdown
    _write_run(tmp_path / "plain", records[3:], version)
    assert report.main([str(tmp_path / "plain"), "--out", str(tmp_path / "plain_out")]) == 0
    assert "emergency_brake" not in json.loads((tmp_path / "plain_out" / "results.json").read_text())
