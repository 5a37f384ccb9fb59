"""The measured figures of the README and of docs/ are exactly what the committed benchmark records say."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from msfsu_evaluation.reports import blocks, generators, prose_figures as prose_figures_module, release

ROOT = Path(__file__).resolve().parent.parent

def command(name: str) -> str:
    """The console script `name`, next to this interpreter as `make setup` installs it (the venv need not be on PATH)."""
    path = Path(sys.executable).with_name(name)
    assert path.is_file(), f"{path} is not installed: make setup"
    return str(path)

# a cell of results.json as msfsu-benchmark-report writes it (closed_loop.cells.SummaryCell)
CELL = {"episodes": 10, "successes": 7, "success_rate": 0.7, "success_ci95": [0.3968, 0.8922], "route_completion": 0.8,
        "driving_score": 0.7, "km_driven": 1.0, "infractions": {}, "infractions_per_km": {},
        "outcomes": {"success": 7, "timeout": 3}, "collisions": {}, "wall_s_per_episode": 10.0, "rmse_m": None,
        "path_rmse_m": None, "rmse_episodes": 0}


@pytest.fixture(scope="module")
def readme_results():
    """The blocks' generators (msfsu_evaluation.reports.generators)."""
    return generators


def test_readme_results_blocks_match_the_committed_records():
    """Every page's blocks (README.md, docs/*.md, docs/results/README.md), each generator's block on one page."""
    check = subprocess.run([command("msfsu-results-blocks"), "--check"], cwd=ROOT, capture_output=True, text=True)
    assert check.returncode == 0, check.stderr


def test_the_pages_with_blocks_are_listed_for_a_commit_to_take_with_the_records():
    listed = subprocess.run([command("msfsu-results-blocks"), "--list"], cwd=ROOT, capture_output=True, text=True,
                            check=True).stdout.splitlines()
    assert {"README.md", "docs/training.md", "docs/deployment.md"} <= set(listed)  # the stages' hours, the gate table
    assert all("<!-- results:" in (ROOT / page).read_text() for page in listed)
    assert "docs/decisions.md" not in listed  # no block: hand edits there are never swept into a stage's commit


def test_the_blocks_are_written_on_every_hand_written_page(readme_results):
    names = [page.relative_to(ROOT).as_posix() for page in blocks.pages()]
    assert names[0] == "README.md" and names[-1] == "docs/results/README.md"
    assert {"docs/realtime.md", "docs/deployment.md", "docs/simulator.md"} <= set(names)
    on_pages = {match.group("name") for page in blocks.pages() if page.exists()
                for match in blocks.BLOCK.finditer(page.read_text())}
    assert on_pages == set(blocks.GENERATORS)


def test_a_block_off_every_page_or_on_two_is_a_problem(readme_results):
    texts = {page: page.read_text() for page in blocks.pages() if page.exists()}
    assert blocks.placement(texts) == []
    soak_page = next(page for page, text in texts.items() if "<!-- results:soak -->" in text)
    without = {**texts, soak_page: blocks.BLOCK.sub(
        lambda m: "" if m.group("name") == "soak" else m.group(0), texts[soak_page])}
    assert blocks.placement(without) == [
        "block 'soak' is on no page: place it with its topic or remove its generator"]
    twice = {**texts, ROOT / "README.md": texts[ROOT / "README.md"] + "<!-- results:soak -->\n<!-- /results:soak -->\n"}
    assert "block 'soak' stands on 2 pages (README.md, docs/realtime.md): keep one" in blocks.placement(twice)


def test_a_blocks_links_are_rewritten_for_the_page_it_stands_on(readme_results):
    body = ("[a](benchmarks/soak/800x600_30hz.md) [b](docs/realtime.md#soak) [c](https://example.org/x) "
            "[d](#here)")
    assert blocks.relocate(body, ROOT / "README.md") == body
    assert blocks.relocate(body, ROOT / "docs" / "realtime.md") == (
        "[a](../benchmarks/soak/800x600_30hz.md) [b](realtime.md#soak) [c](https://example.org/x) [d](#here)")
    assert blocks.relocate(body, ROOT / "docs" / "results" / "README.md").startswith(
        "[a](../../benchmarks/soak/800x600_30hz.md) [b](../realtime.md#soak)")


def test_the_headline_block_holds_the_paper_comparison_the_ablation_and_one_line_per_speed(readme_results):
    block = readme_results.headline()
    assert block.startswith(readme_results.against_paper(("msfsu",)))
    assert "| msfsu |" in block and "| msf |" not in block  # the shipped model only; the ablation is one line
    lines = [line for line in block.splitlines() if line.startswith("- **")]
    v3_ablation = ["Ablation, model v3"] if readme_results.model_v3_ablation_line() else []  # once judged
    from msfsu_evaluation.reports.ability_blocks import BRAKE_RUNS
    from msfsu_evaluation.reports.aeb_goals import ROUTE_RUNS, aeb_goals

    route_runs = [run for run in ROUTE_RUNS if aeb_goals(run) is not None]  # once all its agents share a route
    brake = [run.title for run in route_runs]
    last_brake_run = [run.page for run in BRAKE_RUNS if run.results.exists()][-1]  # the abilities line ends with it
    assert [line.split("**")[1] for line in lines] == ["Ablation", "Deployed precision", "Model v3", *v3_ablation,
                                                       "A network that waits", "Per-ability scenarios", *brake,
                                                       "Perception",
                                                       "Real-time latency", "Simulator speed"]
    assert [line.rsplit("](", 1)[1].split("#")[0] for line in lines] == [
        "docs/results/README.md", "docs/results/README.md", readme_results.model_v3_line().rsplit("](", 1)[1].split(
            "#")[0], *["docs/results/closed_loop_v3_model_v3/results.md"] * len(v3_ablation), "docs/training.md",
        last_brake_run,
        *[run.page for run in route_runs], "docs/deployment.md", "docs/realtime.md",
        "docs/simulator.md"]
    # the run's msfsu_fp32 is MSFSU's checkpoint on fp32: the precision check, not a network of the ablation
    ablation, precision = lines[:2]
    assert "msfsu_fp32" not in ablation and "msf train" in ablation
    assert "msfsu_fp32 train" in precision and "(cpu openvino/int8)" in precision


def test_the_current_run_says_how_far_it_is_until_every_agent_has_every_route(readme_results, tmp_path, monkeypatch):
    run, results = tmp_path / "run.json", tmp_path / "results.json"
    run.write_text(json.dumps({"agents": {"expert": None, "msfsu": "m.pt", "msf": "f.pt"}}))
    report = {"agents": ["expert", "msfsu", "msf"], "results": {}}
    monkeypatch.setattr(readme_results, "CURRENT_RUN", run)
    monkeypatch.setattr(readme_results, "CURRENT_RESULTS", results)
    results.write_text(json.dumps({**report, "sources": {"expert": {"d": 350}, "msfsu": {"d": 90}}}))
    assert readme_results.current_progress() == (
        "In progress: 440 of 1050 episodes driven (expert 350, msfsu 90, msf 0); "
        "`NETWORKS=1 WORKERS=2 bash scripts/results.sh` resumes the run.")
    results.write_text(json.dumps({**report, "sources": {a: {"d": 350} for a in ("expert", "msfsu", "msf")}}))
    assert readme_results.current_progress() == ""


def test_the_model_v3_line_says_its_stages_then_v3_msfsu_against_the_shipped_one_then_the_release(
        readme_results, tmp_path, monkeypatch):
    model_v3_release = release
    plan, done, _ = readme_results.read_recipe(readme_results.MODEL_V3)
    line = readme_results.model_v3_line()
    assert f"{len(done)} of {len(plan.stages)} stages finished" in line
    # judged: here the shipped MSFSU's own episodes under the v3 name, so +0 and no release
    judged = tmp_path / "judge-msfsu"
    judged.mkdir()
    baseline_run = ROOT / model_v3_release.BASELINE.split(":")[0]
    with (judged / "episodes.jsonl").open("w") as out:
        for line in (baseline_run / "episodes.jsonl").read_text().splitlines():
            episode = json.loads(line)
            if episode["agent"] == "msfsu":
                out.write(json.dumps({**episode, "agent": "msfsu_v3"}) + "\n")
    monkeypatch.setattr(model_v3_release, "CANDIDATE", f"{judged}:msfsu_v3")
    monkeypatch.setattr(readme_results, "MODEL_V3", tmp_path / "model_v3")
    (tmp_path / "model_v3").mkdir()
    (tmp_path / "model_v3" / "plan.json").write_text((ROOT / "docs/results/model_v3/plan.json").read_text())
    line = readme_results.model_v3_line()
    stages = len(readme_results.read_recipe(readme_results.MODEL_V3).plan.stages)
    assert f"0 of {stages} stages finished, 0.0 h spent" in line
    assert "v3 MSFSU minus the shipped one: +0 (-1 to +1) (McNemar p 1.000, 350 routes)" in line
    assert "the release rule would not release it" in line
    verdict = release.ReleaseVerdict("b:msfsu", "c:msfsu_v3", False, ["all routes: x"], [])
    (tmp_path / "model_v3" / "release.json").write_text(verdict.to_json())
    assert readme_results.model_v3_line().endswith("; release: not released, all routes: x.")


def test_the_model_v3_ablation_line_pools_v3_msfsu_against_each_other_v3_network_once_judged(
        readme_results, tmp_path, monkeypatch):
    results = tmp_path / "results.json"
    monkeypatch.setattr(readme_results, "MODEL_V3_RESULTS", results)
    assert readme_results.model_v3_ablation_line() == ""  # not judged yet
    row = {"suite": "all", "routes": 175, "only_a": 3, "only_b": 9, "mcnemar_p": 0.146}

    def paired(a: str, b: str, condition: str, a_successes: int, b_successes: int) -> dict:
        difference = (a_successes - b_successes) / 175
        return {**row, "a": a, "b": b, "condition": condition, "a_successes": a_successes,
                "b_successes": b_successes, "difference": difference,
                "difference_ci95": [difference - 0.05, difference + 0.05]}

    results.write_text(json.dumps({"agents": [], "results": {}, "paired": [
        paired("msf_v3", "msfsu_v3", "heldout", 150, 156), paired("msfsu_v3", "su_v3", "train", 160, 150),
        paired("msf_v3", "su_v3", "train", 140, 150), {**paired("msfsu_v3", "su_v3", "train", 60, 50), "suite": "x"},
        paired("expert", "msfsu_v3", "train", 170, 160)]}))
    line = readme_results.model_v3_ablation_line()
    assert line.startswith("- **Ablation, model v3**, v3 MSFSU minus")
    # v3 MSFSU first (its row against MSF turned round), pooled rows only, the expert and pairs without it left out
    assert line.split(": ", 1)[1].split(" ([")[0] == (
        "msf_v3 heldout +3 (-2 to +8) (p 0.146, 175 routes); su_v3 train +6 (+1 to +11) (p 0.146, 175 routes)")


def test_a_stale_block_is_detected(readme_results):
    stale = "<!-- results:simulator-speed -->\n| typed by hand |\n<!-- /results:simulator-speed -->\n"
    assert blocks.render(stale) != stale
    assert blocks.render(blocks.render(stale)) == blocks.render(stale)


def _perception_model(model: str, checkpoint: str | None, paths: dict, fastest: dict | None) -> dict:
    return {"model": model, "checkpoint": checkpoint, "checkpoint_digest": checkpoint and "0123456789abcdef",
            "load_average_before": [0.5, 0.6, 0.7], "paths": paths,
            "verdicts": {"openvino int8": True} if fastest else {},
            "verdict_source": "this run" if fastest else "random weights: no verdicts", "fastest_gated": fastest}


def test_the_perception_speed_block_renders_each_machines_record(readme_results, tmp_path):
    fastest = {"path": "openvino int8", "p50_ms": 4.0, "hz": 250.0, "speedup_vs_torch_fp32": 5.0}
    models = [_perception_model("cpu preset", "models/msfsu_default.pt",
                                {"torch fp32": {"p50_ms": 20.0, "p95_ms": 21.0},
                                 "openvino int8": {"p50_ms": 4.0, "p95_ms": 4.5}}, fastest),
              _perception_model("paper", None, {"torch fp32": {"p50_ms": 100.0, "p95_ms": 101.0}}, None)]
    record = {"date": "2026-11-23 21:00 UTC", "command": "python x", "machine": "x86_64, 2 CPUs", "threads": 2,
              "iterations": 40, "torch": "2.13.0+cpu", "models": models, "end_to_end": []}
    (tmp_path / "perception_results.json").write_text(json.dumps(record))
    perception_speed = readme_results.RECORD_BLOCKS["perception-speed"]
    block = perception_speed(tmp_path)
    assert "| cpu preset (`models/msfsu_default.pt`) | 20.0 ms (50 Hz) | - | - | 4.0 ms (250 Hz) | " \
           "**openvino int8: 4.0 ms, 250 Hz, 5.0x** | 0.5 |" in block
    assert "| paper (`random`) | 100.0 ms (10 Hz) | - | - | - | - | 0.5 |" in block
    assert "AVX2" not in block  # no record of the AVX2-only machine: one table
    (tmp_path / "perception_results_avx2.json").write_text(json.dumps({**record, "machine": "AMD EPYC, 2 CPUs"}))
    assert perception_speed(tmp_path).startswith(block + "\n\nOn a CPU with AVX2 only")
    assert perception_speed.record().main.headline().startswith("- **Perception**, the shipped model on ")


def test_the_closed_loop_block_has_every_agent_and_condition_with_intervals(readme_results, tmp_path):
    assert "No closed-loop records" in readme_results.closed_loop(tmp_path / "missing.json")
    cell = CELL
    record = {"agents": ["expert", "msfsu"],
              "results": {"expert": {"nocrash": {"nocrash_dense": {"train": cell, "heldout": cell},
                                                 "nocrash_empty": {"train": cell}}},
                          "msfsu": {"nocrash": {"nocrash_dense": {"heldout": cell}}}}}
    (tmp_path / "results.json").write_text(json.dumps(record))
    lines = readme_results.closed_loop(tmp_path / "results.json").splitlines()
    assert lines[0] == "| suite / task | train: expert | train: msfsu | heldout: expert | heldout: msfsu |"
    assert [line.split(" | ")[0] for line in lines[2:]] == ["| nocrash / nocrash_empty", "| nocrash / nocrash_dense"]
    assert lines[3] == "| nocrash / nocrash_dense | 7/10 (70 %; 40-89) | - | 7/10 (70 %; 40-89) | 7/10 (70 %; 40-89) |"


def test_the_closed_loop_block_pools_the_paired_comparison_with_msfsu_first(readme_results, tmp_path):
    cell = CELL
    paired = {"a": "msf", "b": "msfsu", "condition": "heldout", "routes": 70, "a_successes": 50, "b_successes": 60,
              "only_a": 2, "only_b": 12, "difference": -0.1429, "difference_ci95": [-0.24, -0.05], "mcnemar_p": 0.013}
    record = {"agents": ["expert", "msf", "msfsu"],
              "results": {agent: {"nocrash": {"nocrash_dense": {"heldout": cell}}} for agent in ("expert", "msf", "msfsu")},
              "paired": [{**paired, "suite": "nocrash"}, {**paired, "suite": "all"}]}
    (tmp_path / "results.json").write_text(json.dumps(record))
    block = readme_results.closed_loop(tmp_path / "results.json")
    assert "| msfsu vs msf | heldout | 70 | 60 | 50 | 12 | 2 | +14 (+5 to +24) | 0.013 |" in block
    assert block.count("vs msf |") == 1  # only the pooled ("all") row


def test_the_int8_profile_block_sets_the_two_exported_graphs_side_by_side(readme_results, tmp_path):
    def graph(wall, float_ms, int8_ms):
        return {"wall_p50_ms": wall, "layers_ms": float_ms + int8_ms,
                "by_kind": [{"kind": "ConvolutionBackpropData (brgconv_avx512_f32)", "ms": float_ms},
                            {"kind": "Convolution (brgconv_avx512_1x1_I8)", "ms": int8_ms}], "top_layers": []}

    record = {"date": "2026-11-24 18:00 UTC", "command": "python x", "machine": "x86_64, 2 CPUs", "threads": 2,
              "iterations": 100, "models": [{"checkpoint": "runs/p/best.pt", "checkpoint_digest": "0123456789abcdef",
                                             "load_before": 0.1, "graphs": {"deployed": graph(8.0, 0.5, 7.0),
                                                                            "as in torch": graph(12.0, 6.0, 6.0)}}]}
    (tmp_path / "int8_profile_results.json").write_text(json.dumps(record))
    block = readme_results.RECORD_BLOCKS["int8-profile"](tmp_path / "int8_profile_results.json")
    assert ("| `runs/p/best.pt` | 12.0 ms (6.0 ms of 12.0 in float kernels) | 8.0 ms (0.5 ms of 7.5 in float kernels) "
            "| 1.50x | 0.1 |") in block


def test_the_paper_training_line_reads_the_short_runs_record(readme_results, tmp_path, monkeypatch):
    monkeypatch.setattr(readme_results, "TRAINING_RECORDS", tmp_path)
    assert "no training record yet" in readme_results.paper_training()
    (tmp_path / "paper_short").mkdir()
    (tmp_path / "paper_short" / "metrics.csv").write_text("epoch,samples_per_s,epoch_time_s\n0,10.0,60\n1,20.0,180\n")
    (tmp_path / "paper_short" / "args.json").write_text(json.dumps(
        {"bf16": True, "channels_last": False, "decoder_layout": "v2", "max_steps": 50}))
    assert readme_results.paper_training().startswith(
        "Training on 2 cores, paper preset: 17.5 samples/s (bf16, decoder v2; the int8 gate's short run, 50 steps in "
        "4.0 min")


def soak_record(size: str, rate_hz: float, p95: float, brakes: int = 0) -> dict:
    e2e = {"n": 100, "p50": 12.0, "p95": p95, "p99": p95 + 2, "max": p95 + 10}
    return {"started_utc": "2026-11-25 20:10 UTC", "minutes": 10.0, "size": size, "camera": f"{size} rgb8 + 32FC1",
            "rate_hz": rate_hz, "checkpoint": "/somewhere/models/msfsu_default.pt",
            "inference": "openvino/int8, warm-up inference 6 ms", "machine": "x86_64, 2 logical CPUs",
            "load_average_start": "0.10 0.2 0.3", "load_average_end": "1.50 1.2 1.0", "slow_ms": 50.0,
            "slow_causes": {"DDS: rgb to perception": 3},
            "stages": [{"stage": "perception: network", "p50": 4.4, "p95": 5.8}],
            "totals": {"published": 18000, "answered": 17990, "skipped": 10, "unpaired": 0,
                       "answered_or_skipped_share": 1.0, "watchdog_brakes_driving": brakes, "end_to_end_ms": e2e}}


def test_the_soak_blocks_read_every_soak_record(readme_results, tmp_path):
    assert "Not soaked yet" in readme_results.soak(tmp_path)
    for name, record in {"800x600_30hz": soak_record("800x600", 30.0, 15.3),
                         "1920x1080_30hz": soak_record("1920x1080", 30.0, 70.0),
                         "800x600_20hz": soak_record("800x600", 20.0, 14.0, brakes=1)}.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(record))
    rows = readme_results.soak(tmp_path).splitlines()
    assert [row.split(" | ")[:2] for row in rows[2:5]] == [["| 800x600", "20 Hz"], ["| 800x600", "30 Hz"],
                                                          ["| 1920x1080", "30 Hz"]]
    assert "p95 <= 25, max < 100: **not met**" in rows[2]  # one watchdog brake while driving
    assert "12.0 / 15.3 / 17.3 / 25.3 | p95 <= 30, max < 100: met" in rows[3]
    assert "p95 <= 60: **not met**" in rows[4] and "[1920x1080_30hz](benchmarks/soak/1920x1080_30hz.md)" in rows[4]
    stages = readme_results.soak_stages(tmp_path)
    assert "| perception: network | 4.4 / 5.8 | 4.4 / 5.8 | 4.4 / 5.8 |" in stages
    assert "1920x1080 at 30 Hz: 3 DDS: rgb to perception" in stages


def test_the_design_table_names_each_soak_by_its_file(readme_results, tmp_path):
    (tmp_path / "thread_defaults_800x600_30hz.json").write_text(json.dumps(soak_record("800x600", 30.0, 150.0)))
    table = readme_results.soak_design(tmp_path)
    assert "| in a thread of its own (before) | Fast DDS defaults (before) | 800x600 at 30 Hz | 18,000 |" in table


@pytest.fixture(scope="module")
def prose_figures():
    return prose_figures_module


def test_every_figure_in_the_prose_is_a_registered_setting_or_sourced():
    check = subprocess.run([command("msfsu-prose-figures")], cwd=ROOT, capture_output=True, text=True)
    assert check.returncode == 0, check.stderr


def test_a_typed_figure_outside_generated_blocks_is_caught_and_blocks_code_and_links_are_not(prose_figures):
    text = ("The simulator runs 23.3 steps/s and MSFSU won 24/25 held out.\n"
            "<!-- results:simulator-speed -->\n| evaluation | 23.29 steps/s |\n<!-- /results:simulator-speed -->\n"
            "<!-- generated:node-parameters -->\n| `rate` | 10 Hz |\n<!-- /generated:node-parameters -->\n"
            "```bash\nsleep 5 s\n```\nrun `--workers 2` see [x](docs/10%20s.md), a 4.3x speed-up, -1.8 % on them\n")
    found = [(figure.line, figure.text) for figure in prose_figures.figures("README.md", text)]
    assert found == [(1, "23.3 steps/s"), (1, "24/25"), (11, "4.3x"), (11, "1.8 %")]


def test_a_measured_figure_must_be_in_its_source_and_rows_must_stay_in_use(prose_figures, tmp_path):
    (tmp_path / "docs" / "results").mkdir(parents=True)
    pages = ("README.md", "docs/topic.md", "docs/results/README.md")
    for name in pages + ("docs/results/generated.md",):
        (tmp_path / name).write_text("Setup in 10 min; the bag has 99 frames and 12 routes.\n")
    assert prose_figures.prose_pages(tmp_path) == list(pages)  # docs/results/ is generated but for its README
    (tmp_path / "record.md").write_text("| frames | 98 |\n")
    registry = tmp_path / "figures.tsv"
    rows = [f"{name}\t{figure}\t{kind}\t{note}" for name in pages for figure, kind, note in
            (("10 min", "setting", "the CI budget"), ("99 frames", "measured", "record.md frames"))]
    registry.write_text("\n".join(rows + ["README.md\t7 s\tsetting\tgone from the text"]) + "\n")
    issues = prose_figures.problems(tmp_path, registry)
    files = len(pages)
    assert sum("'12 routes' in prose is not registered" in issue for issue in issues) == files
    assert sum("record.md does not hold that number" in issue for issue in issues) == files
    assert any("'7 s' is registered for README.md but no longer there" in issue for issue in issues)
    (tmp_path / "record.md").write_text("| frames | 99 |\n")
    assert len(prose_figures.problems(tmp_path, registry)) == files + 1  # one unregistered per file + 1 stale row


def test_the_nodes_page_lists_every_parameter_as_the_nodes_declare_it():
    check = subprocess.run([command("msfsu-node-parameters"), "--check"], cwd=ROOT,
                           capture_output=True, text=True)
    assert check.returncode == 0, check.stderr
    page = (ROOT / "docs" / "nodes.md").read_text()
    assert "| `kp` | live | `5.0` | 0.0 to 100.0 | proportional gain (per sample) |" in page
    assert "| `checkpoint` | read-only | `\"\"` |  | MSFSU checkpoint file (.pt) written by msfsu-train |" in page


def test_a_nodes_page_without_its_block_is_a_one_line_error(tmp_path, capsys):
    from msfsu_evaluation.reports import node_parameters

    page = tmp_path / "nodes.md"
    page.write_text("# Nodes\n")
    assert blocks.rewrite_page(page, node_parameters.render, "msfsu-node-parameters", "", ["--check"]) == 1
    assert capsys.readouterr().err == "msfsu-node-parameters: nodes.md needs exactly one node-parameters block, found 0\n"
    assert blocks.rewrite_page(tmp_path / "gone.md", node_parameters.render, "msfsu-node-parameters", "", []) == 1
    assert capsys.readouterr().err.count("\n") == 1


def test_the_precision_block_pairs_msfsu_with_its_own_checkpoint_on_fp32_only(readme_results):
    block = readme_results.closed_loop_precision()
    rows = [line.split(" | ") for line in block.splitlines() if line.startswith("| msfsu_fp32 |")]
    assert rows and {row[1] for row in rows} <= {"corl2017", "nocrash", "all"}
    assert "| msf |" not in block and "| su |" not in block  # other networks are the ablation's
    assert "cpu openvino/int8" in block.splitlines()[0]
