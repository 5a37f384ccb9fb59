"""The README's measured figures are exactly what the committed benchmark records say."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def readme_results():
    """scripts/readme_results.py as a module."""
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import readme_results
    finally:
        sys.path.pop(0)
    return readme_results


def test_readme_results_blocks_match_the_committed_records():
    check = subprocess.run([sys.executable, "scripts/readme_results.py", "--check"], cwd=ROOT,
                           capture_output=True, text=True)
    assert check.returncode == 0, check.stderr


def test_a_stale_block_is_detected(readme_results):
    stale = "<!-- results:simulator-speed -->\n| typed by hand |\n<!-- /results:simulator-speed -->\n"
    assert readme_results.render(stale) != stale
    assert readme_results.render(readme_results.render(stale)) == readme_results.render(stale)


def test_the_perception_speed_block_renders_a_benchmark_record_and_says_when_there_is_none(readme_results, tmp_path):
    assert "Not measured yet" in readme_results.perception_speed(tmp_path / "missing.json")
    path = {"p50_ms": 4.0, "p95_ms": 4.5}
    record = {"date": "2026-11-23 21:00 UTC", "machine": "x86_64, 2 CPUs", "threads": 2, "command": "python x",
              "models": [{"model": "cpu preset", "checkpoint": "models/msfsu_default.pt", "load_average_before":
                          [0.5, 0.6, 0.7], "paths": {"torch fp32": {"p50_ms": 20.0, "p95_ms": 21.0},
                                                      "openvino int8": path},
                          "fastest_gated": {"path": "openvino int8", "p50_ms": 4.0, "hz": 250.0,
                                            "speedup_vs_torch_fp32": 5.0}},
                         {"model": "paper", "checkpoint": None, "load_average_before": [0.5, 0.6, 0.7],
                          "paths": {"torch fp32": {"p50_ms": 100.0, "p95_ms": 101.0}}, "fastest_gated": None}]}
    (tmp_path / "perception_results.json").write_text(json.dumps(record))
    block = readme_results.perception_speed(tmp_path / "perception_results.json")
    assert "| cpu preset (`models/msfsu_default.pt`) | 20.0 ms (50 Hz) | - | - | 4.0 ms (250 Hz) | " \
           "**openvino int8: 4.0 ms, 250 Hz, 5.0x** | 0.5 |" in block
    assert "| paper (`random`) | 100.0 ms (10 Hz) | - | - | - | - | 0.5 |" in block


def test_the_closed_loop_block_has_every_agent_and_condition_with_intervals(readme_results, tmp_path):
    assert "No closed-loop records" in readme_results.closed_loop(tmp_path / "missing.json")
    cell = {"episodes": 10, "successes": 7, "success_rate": 0.7, "success_ci95": [0.3968, 0.8922]}
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
    cell = {"episodes": 10, "successes": 7, "success_rate": 0.7, "success_ci95": [0.3968, 0.8922]}
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
    assert "Not profiled yet" in readme_results.int8_profile(tmp_path / "missing.json")

    def graph(wall, float_ms, int8_ms):
        return {"wall_p50_ms": wall, "layers_ms": float_ms + int8_ms,
                "by_kind": [{"kind": "ConvolutionBackpropData (brgconv_avx512_f32)", "ms": float_ms},
                            {"kind": "Convolution (brgconv_avx512_1x1_I8)", "ms": int8_ms}]}

    record = {"date": "2026-11-24 18:00 UTC", "machine": "x86_64, 2 CPUs", "threads": 2, "command": "python x",
              "models": [{"checkpoint": "runs/p/best.pt", "load_before": 0.1,
                          "graphs": {"deployed": graph(8.0, 0.5, 7.0), "as in torch": graph(12.0, 6.0, 6.0)}}]}
    (tmp_path / "int8_profile_results.json").write_text(json.dumps(record))
    block = readme_results.int8_profile(tmp_path / "int8_profile_results.json")
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


def test_the_soak_paragraph_reads_the_soak_totals(readme_results, tmp_path):
    assert "Not soaked yet" in readme_results.soak(tmp_path / "missing.json")
    latency = {"p50": 40.4, "p95": 90.6, "max": 300.2}
    record = {"started_utc": "2026-11-24 18:30 UTC", "minutes": 10.0, "camera": "800x600 rgb8 + 32FC1", "rate_hz": 30.0,
              "checkpoint": "/somewhere/models/msfsu_default.pt", "inference": "openvino/int8",
              "machine": "x86_64, 2 logical CPUs", "load_average_end": "3.1 2.9 2.0",
              "totals": {"published": 18000, "answered": 15000, "processed": 15000, "skipped": 2900, "dropped": 100,
                         "action_latency_ms": latency, "control_latency_ms": latency,
                         "rss_mb_after_warmup": {"perception": 500.0, "control": 68.0},
                         "rss_mb_end": {"perception": 501.0, "control": 68.0},
                         "rss_growth_mb_per_min": {"perception": 0.11, "control": 0.0}},
              "diagnostics": {"msfsu/control": {"watchdog_brakes": "3", "rejected_actions": "0"}}}
    (tmp_path / "soak_results.json").write_text(json.dumps(record))
    text = readme_results.soak(tmp_path / "soak_results.json")
    assert text.startswith("2026-11-24 18:30 UTC: 800x600 rgb8 + 32FC1 at 30 Hz for 10 minutes, "
                           "`models/msfsu_default.pt` on openvino/int8")
    assert "18,000 frames published, 15,000 processed, 2,900 skipped for a newer frame, 100 unpaired" in text
    assert "p50 40 ms, p95 91 ms, max 300 ms" in text and "perception 500.0 -> 501.0 MB (+0.11 MB/min)" in text
    assert text.endswith("control watchdog brakes 3, rejected actions 0.")
