"""The msfsu-train CLI end to end on small synthetic bags: single process, resume, and DDP."""

import csv
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from msfsu_common.road_option import RoadOption
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.checkpoint import load_checkpoint
from msfsu_perception.inference import DrivingModel
from msfsu_perception.synthetic import write_synthetic_bag
from msfsu_perception.train import main
from msfsu_perception.training_settings import parse_args

SMOKE = ["--preset", "cpu", "--batch-size", "8", "--max-samples", "12", "--num-threads", "1"]


@pytest.fixture(scope="module")
def bag_glob(tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    write_synthetic_bag(root / "train", 30, "train", seed=1)
    write_synthetic_bag(root / "validation", 16, "validation", seed=2)
    return str(root / "*")


def _rows(run):
    with (run / "metrics.csv").open() as stream:
        return list(csv.DictReader(stream))


def test_ddp_two_process_gloo_run(bag_glob, tmp_path):
    run = tmp_path / "ddp"
    command = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
        "-m", "msfsu_perception.train", "--bags", bag_glob, "--out", str(run),
        "--cache-dir", str(tmp_path / "cache"), "--epochs", "1", "--device", "cpu", *SMOKE,
    ]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    checkpoint = load_checkpoint(run / "best.pt")
    assert checkpoint.training["world_size"] == 2
    assert len(_rows(run)) == 1  # one writer: rank 0
    assert all(torch.isfinite(p).all() for p in checkpoint.model.parameters())


def test_msf_variant_trains_without_scene_loss_or_labels(bag_glob, tmp_path):
    run = tmp_path / "msf"
    main(["--bags", bag_glob, "--out", str(run), "--cache-dir", str(tmp_path / "cache"), "--variant", "msf",
          "--epochs", "1", *SMOKE])
    row = _rows(run)[0]
    assert row["train_scene"] == row["val_scene"] == "nan" and float(row["val_total"]) > 0
    assert not DrivingModel.from_checkpoint(run / "best.pt").has_segmentation
    assert not list((tmp_path / "cache").glob("*/class_ids.npy"))


def test_topics_can_be_remapped_on_the_command_line():
    args = parse_args(["--bags", "b", "--out", "o", "--topic", "rgb=/cam/rgb", "--topic", "depth=/cam/depth"])
    assert args.topics == BagTopics(rgb="/cam/rgb", depth="/cam/depth")
    with pytest.raises(SystemExit):
        parse_args(["--bags", "b", "--out", "o", "--topic", "lidar=/points"])


def test_max_steps_ends_a_short_run_inside_its_first_epoch_with_a_usable_checkpoint(bag_glob, tmp_path):
    run = tmp_path / "run"
    main(["--bags", bag_glob, "--out", str(run), "--cache-dir", str(tmp_path / "cache"), "--preset", "cpu",
          "--batch-size", "2", "--max-samples", "12", "--num-threads", "1", "--epochs", "5", "--max-steps", "2"])
    rows = _rows(run)
    assert [row["epoch"] for row in rows] == ["0"]  # the budget ran out in epoch 0: no second epoch
    state = load_checkpoint(run / "last.pt", with_training_state=True)
    assert state.training_state["steps"] == 2 and state.training["steps"] == 2
    assert (run / "best.pt").is_file()
    with pytest.raises(SystemExit):
        parse_args(["--bags", bag_glob, "--out", str(run), "--max-steps", "0"])


def test_settings_left_open_come_from_the_preset_and_on_a_gpu_from_its_gpu_defaults():
    from msfsu_perception.training_settings import PRESETS, resolve_settings

    def resolved(device: str, *argv: str, cpu_bf16: bool = True):
        args = parse_args(["--bags", "x", "--out", "y", *argv])
        # a CUDA device object needs no GPU; cpu_bf16 stands for the CPU's answer (avx512_bf16 / AMX or not)
        resolve_settings(args, PRESETS[args.preset], torch.device(device), cpu_bf16=lambda: cpu_bf16)
        return args.batch_size, args.learning_rate, args.bf16, args.channels_last, args.workers

    assert resolved("cpu", "--preset", "paper") == (32, 3e-4, False, False, 0)  # the paper's recipe
    batch, lr, bf16, channels_last, workers = resolved("cuda", "--preset", "paper")
    assert (batch, bf16, channels_last) == (256, True, True) and lr == pytest.approx(3e-4 * (256 / 32) ** 0.5, 1e-3)
    assert 1 <= workers <= 16
    assert resolved("cuda", "--preset", "paper", "--batch-size", "32", "--learning-rate", "3e-4", "--no-bf16",
                    "--workers", "3")[:5] == (32, 3e-4, False, True, 3)
    assert resolved("cuda", "--preset", "paper", "--batch-size", "64")[:2] == (64, 3e-4)  # no GPU default batch: the preset's rate
    assert resolved("cpu", "--preset", "cpu")[:4] == (32, 3e-4, True, True)
    # without native bf16 (an AVX2-only CPU) the cpu preset trains in fp32: emulated bf16 is many times slower;
    # an explicit --bf16 still holds, and a GPU needs no CPU bf16
    assert resolved("cpu", "--preset", "cpu", cpu_bf16=False)[:4] == (32, 3e-4, False, True)
    assert resolved("cpu", "--preset", "cpu", "--bf16", cpu_bf16=False)[2] is True
    assert resolved("cuda", "--preset", "cpu", cpu_bf16=False)[2] is True


def test_loader_workers_default_to_none_on_the_cpu_and_all_cpus_but_one_on_a_gpu():
    from msfsu_perception.training_settings import default_workers

    assert default_workers(torch.device("cpu"), cpus=64) == 0
    assert [default_workers(torch.device("cuda"), cpus=n) for n in (1, 2, 16, 64)] == [1, 1, 15, 16]


def test_the_loss_meter_sums_on_the_device_to_the_sample_weighted_means():
    from msfsu_perception.distributed import init_distributed
    from msfsu_perception.losses import LossTerms
    from msfsu_perception.training_state import LossMeter

    context = init_distributed("cpu")
    meter = LossMeter(context.device)
    meter.add(LossTerms(*(torch.tensor(v) for v in (1.0, 2.0, 3.0)), None), 2)
    meter.add(LossTerms(*(torch.tensor(v) for v in (4.0, 5.0, 6.0)), None), 1)
    assert meter.mean_total() == pytest.approx(2.0)
    means = meter.means(context, has_scene=False)
    assert means["total"] == pytest.approx(2.0) and means["steer"] == pytest.approx(3.0)
    assert means["speed"] == pytest.approx(4.0) and np.isnan(means["scene"])



RESUMABLE = ["--preset", "cpu", "--batch-size", "8", "--max-samples", "12", "--num-threads", "1", "--epochs", "2"]


@pytest.fixture(scope="module")
def unbroken_run(bag_glob, tmp_path_factory):
    """Two epochs never stopped: what a stopped and resumed run must end with."""
    root = tmp_path_factory.mktemp("unbroken")
    main(["--bags", bag_glob, "--cache-dir", str(root / "cache"), "--out", str(root / "run"), *RESUMABLE])
    return root


def test_training_writes_checkpoints_logs_and_plots(unbroken_run):
    run = unbroken_run / "run"
    for name in ("best.pt", "last.pt", "loss_curves.png", "balancing.png", "args.json"):
        assert (run / name).is_file(), name
    rows = _rows(run)
    assert [row["epoch"] for row in rows] == ["0", "1"]
    assert float(rows[0]["lr"]) == pytest.approx(3e-4)
    assert float(rows[0]["samples_per_s"]) > 0 and float(rows[0]["step_time_s"]) > float(rows[0]["data_time_s"]) > 0
    last = load_checkpoint(run / "last.pt", with_training_state=True)
    # what each epoch drew from (the balanced rows of the bags it read)
    assert [row["train_samples"] for row in rows] == [str(last.training["train_samples"])] * 2
    assert last.training_state["epoch"] == 2 and last.training["epoch"] == 1 and "optimizer" in last.training_state
    assert "partial" not in last.training_state  # saved at an epoch's end

    driving = DrivingModel.from_checkpoint(run / "best.pt")  # what the perception node does
    assert driving.preprocess.input_height == 128 and driving.has_segmentation
    prediction = driving.predict(np.zeros((4, 128, 128), np.float32), RoadOption.LANE_FOLLOW)
    assert prediction.class_ids.shape == (128, 128)


# (stop, pass, epoch, its n-th batch): a crash in a training batch (no handler runs: the periodic save after the
# batch before is what is left), a signal in a training batch, one in a validation batch (the training pass is done:
# resumed, it trains no batch), and a crash in the next epoch's first batch (the last save is the first epoch's end,
# so that resume starts an epoch afresh). The last two are the slow suite's, for time.
STOPS = [pytest.param("crash", "train", 0, 3, id="crash-in-training"),
         pytest.param("signal", "train", 0, 3, id="signal-in-training"),
         pytest.param("signal", "validation", 0, 1, id="signal-in-validation", marks=pytest.mark.slow),
         pytest.param("crash", "train", 1, 1, id="crash-next-epoch", marks=pytest.mark.slow)]


@pytest.mark.parametrize(("stop", "where", "epoch", "nth"), STOPS)
def test_a_stopped_run_resumes_where_it_stopped_and_ends_as_an_unbroken_run(bag_glob, unbroken_run, tmp_path,
                                                                             monkeypatch, capsys, stop, where, epoch,
                                                                             nth):
    """A stop signal (SIGTERM: Ctrl-C and SIGINT take the same path) inside a batch lets the batch end, saves last.pt
    there and exits with one line; after a crash the last periodic save is what is left. Either way --resume
    continues there: same weights and same per-epoch losses as the run never stopped."""
    import signal

    import msfsu_perception.training_pass as training_pass

    loss, seen = training_pass.msfsu_loss, {("train", 0): 0, ("validation", 0): 0, ("train", 1): 0,
                                            ("validation", 1): 0}
    state = {"epoch": 0}

    def loss_then_stop(*args, **kwargs):
        pass_ = "train" if torch.is_grad_enabled() else "validation"
        if pass_ == "train" and seen[("validation", state["epoch"])]:
            state["epoch"] += 1
        seen[(pass_, state["epoch"])] += 1
        if (pass_, state["epoch"]) == (where, epoch) and seen[(where, epoch)] == nth:
            if stop == "signal":
                os.kill(os.getpid(), signal.SIGTERM)  # arrives inside the batch
            else:
                raise RuntimeError("the machine went away")
        return loss(*args, **kwargs)

    run = tmp_path / "run"
    common = ["--bags", bag_glob, "--cache-dir", str(unbroken_run / "cache"), "--out", str(run), *RESUMABLE,
              "--checkpoint-every", "0" if stop == "signal" else "1e-9"]  # the crash case saves after every batch
    monkeypatch.setattr(training_pass, "msfsu_loss", loss_then_stop)
    with pytest.raises(SystemExit if stop == "signal" else RuntimeError) as stopped:
        main(common)
    monkeypatch.undo()
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # main put the handlers back
    saved = load_checkpoint(run / "last.pt", with_training_state=True).training_state
    trained = seen[("train", 0)] if where == "validation" else nth - 1 + (stop == "signal")
    if epoch == 0:
        assert saved["epoch"] == 0 and saved["partial"]["timing"]["batches"] == trained
    else:
        assert saved["epoch"] == 1 and "partial" not in saved
    if stop == "signal":
        message = str(stopped.value)
        assert message.startswith(f"msfsu-train: stopped in epoch 0 after {trained} of ")
        assert message.endswith(f"batches; {run / 'last.pt'} holds it: run again with --resume to continue from there")

    capsys.readouterr()
    main([*common, "--resume"])
    expected = f"in epoch 0 after batch {trained}" if epoch == 0 else "after epoch 0"
    assert f"resuming {expected}" in capsys.readouterr().out
    unbroken = unbroken_run / "run"
    resumed, reference = (load_checkpoint(path / "last.pt").model.state_dict() for path in (run, unbroken))
    assert all(torch.equal(resumed[name], reference[name]) for name in reference)
    columns = ("epoch", "train_total", "train_steer", "val_total")
    assert [[row[c] for c in columns] for row in _rows(run)] == [[row[c] for c in columns] for row in _rows(unbroken)]


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_on_a_gpu_with_loader_workers_a_stopped_run_resumes_where_it_stopped(bag_glob, tmp_path, monkeypatch):
    """The GPU's settings (bf16, channels-last, pinned batches from 2 loader workers) and its random state (dropout
    on the GPU draws from the CUDA generator): stopped in the third batch and resumed, the run ends as it does
    unbroken, within what two unbroken runs differ by (GPU kernels need not be bit-exact)."""
    import signal

    import msfsu_perception.training_pass as training_pass

    common = ["--bags", bag_glob, "--cache-dir", str(tmp_path / "cache"), *RESUMABLE, "--device", "cuda",
              "--workers", "2"]
    for name in ("unbroken", "again"):
        main([*common, "--out", str(tmp_path / name)])
    loss, calls = training_pass.msfsu_loss, []

    def loss_then_stop(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGTERM)
        return loss(*args, **kwargs)

    monkeypatch.setattr(training_pass, "msfsu_loss", loss_then_stop)
    with pytest.raises(SystemExit, match="stopped in epoch 0 after 3 of"):
        main([*common, "--out", str(tmp_path / "resumed")])
    monkeypatch.undo()
    main([*common, "--out", str(tmp_path / "resumed"), "--resume"])
    unbroken, again, resumed = (load_checkpoint(tmp_path / name / "last.pt").model.state_dict()
                                for name in ("unbroken", "again", "resumed"))

    def largest_difference(a, b):
        return max(float((a[name].float() - b[name].float()).abs().max()) for name in a)

    noise, difference = largest_difference(unbroken, again), largest_difference(resumed, unbroken)
    print(f"largest weight difference: unbroken vs unbroken {noise:.3g}, resumed vs unbroken {difference:.3g}")
    assert difference <= 10 * noise + 1e-6


def _weights(path):
    """The learned parameters (batch-norm statistics move in any training pass, whatever the learning rate)."""
    return dict(load_checkpoint(path).model.named_parameters())


def test_a_warm_start_begins_at_the_checkpoint_s_weights_with_a_fresh_optimizer(bag_glob, unbroken_run, tmp_path):
    from msfsu_perception.checkpoint import release_checkpoint

    source = unbroken_run / "run" / "best.pt"
    released = release_checkpoint(source, tmp_path / "released.pt")  # fp16 storage, as models/ ships
    run = tmp_path / "warm"
    # a learning rate too small to move fp32 weights: what the run starts from is what it ends with
    main(["--bags", bag_glob, "--out", str(run), "--cache-dir", str(unbroken_run / "cache"), *SMOKE, "--epochs", "1",
          "--init-from", str(released), "--learning-rate", "1e-30"])
    warm, started_from = _weights(run / "last.pt"), _weights(released)
    assert all(torch.allclose(warm[name], started_from[name], atol=1e-6) for name in warm)
    state = load_checkpoint(run / "last.pt", with_training_state=True)
    assert state.training["init_from"] == str(released) and state.training_state["epoch"] == 1  # a new run's epoch 0
    cold = tmp_path / "cold"
    main(["--bags", bag_glob, "--out", str(cold), "--cache-dir", str(unbroken_run / "cache"), *SMOKE, "--epochs", "1",
          "--learning-rate", "1e-30"])
    assert not all(torch.allclose(w, started_from[name], atol=1e-3) for name, w in _weights(cold / "last.pt").items())


def test_a_stop_output_warm_starts_from_a_network_without_one_and_its_term_enters_the_total(bag_glob, unbroken_run,
                                                                                            tmp_path):
    source = unbroken_run / "run" / "best.pt"  # an MSFSU network without a stop output
    run = tmp_path / "stop"
    main(["--bags", bag_glob, "--out", str(run), "--cache-dir", str(unbroken_run / "cache"), *SMOKE, "--epochs", "1",
          "--init-from", str(source), "--learning-rate", "1e-30", "--stop-output", "--stop-weight", "3"])
    warm, started_from = _weights(run / "last.pt"), _weights(source)
    for name, weight in warm.items():  # every weight the source had; the branches' last layers keep its two rows
        assert torch.allclose(weight[:started_from[name].shape[0]], started_from[name], atol=1e-6), name
    assert load_checkpoint(run / "last.pt").model.config.stop_output
    row = {key: float(value) for key, value in _rows(run)[0].items()}
    assert row["val_stop"] > 0
    assert row["val_total"] == pytest.approx(10 * row["val_steer"] + row["val_speed"] + 2 * row["val_scene"]
                                             + 3 * row["val_stop"], rel=1e-4)
    # the other way round the stop output would be lost: refused
    with pytest.raises(SystemExit, match=r"^msfsu-train: --init-from .* this run trains .*stop_output=False"):
        main(["--bags", str(tmp_path / "no_bags_here"), "--out", str(tmp_path / "plain"), *SMOKE,
              "--init-from", str(run / "last.pt")])


def test_a_warm_start_from_another_network_is_a_one_line_error_before_any_data_is_read(unbroken_run, tmp_path):
    source = str(unbroken_run / "run" / "best.pt")  # an MSFSU network
    with pytest.raises(SystemExit, match=r"^msfsu-train: --init-from .* this run trains .*variant='msf'"):
        main(["--bags", str(tmp_path / "no_bags_here"), "--out", str(tmp_path / "run"), *SMOKE,
              "--variant", "msf", "--init-from", source])
    with pytest.raises(SystemExit, match="^msfsu-train: checkpoint .* does not exist$"):
        main(["--bags", "b", "--out", str(tmp_path / "run"), *SMOKE, "--init-from", str(tmp_path / "none.pt")])
    assert not (tmp_path / "run" / "metrics.csv").exists()


def test_a_warm_start_takes_the_checkpoint_s_decoder_layout_unless_told_otherwise(tmp_path):
    from msfsu_perception.model import MSFSUConfig, build_model
    from msfsu_perception.checkpoint import save_checkpoint
    from msfsu_perception.preprocessing import PreprocessConfig
    from msfsu_perception.training_settings import PRESETS, resolve_settings

    preset = PRESETS["cpu"]
    path = tmp_path / "v1.pt"
    save_checkpoint(path, build_model(preset.model_config("msfsu", "v1")), PreprocessConfig(128, 128))

    def layout(*argv: str) -> str:
        args = parse_args(["--bags", "b", "--out", "o", *argv])
        resolve_settings(args, preset, torch.device("cpu"), cpu_bf16=lambda: True)
        return args.decoder_layout

    assert layout("--init-from", str(path)) == "v1" and layout() == MSFSUConfig.decoder_layout == "v2"
    assert layout("--init-from", str(path), "--decoder-layout", "v2") == "v2"


def test_the_scene_weight_sets_the_scene_loss_s_share_of_the_total(bag_glob, tmp_path):
    totals = {}
    for weight in ("0", "5"):
        run = tmp_path / weight
        main(["--bags", bag_glob, "--out", str(run), "--cache-dir", str(tmp_path / "cache"), *SMOKE, "--epochs", "1",
              "--scene-weight", weight])
        row = {key: float(value) for key, value in _rows(run)[0].items()}
        totals[weight] = row
        # eq. 5 with lambda1 = 10, lambda2 = 1 and the weight asked for, on the validation pass (no weights change)
        assert row["val_total"] == pytest.approx(10 * row["val_steer"] + row["val_speed"] + float(weight) * row["val_scene"],
                                                 rel=1e-4)
    assert totals["5"]["val_scene"] > 0
    with pytest.raises(SystemExit):
        parse_args(["--bags", "b", "--out", "o", "--scene-weight", "-1"])


def test_a_run_whose_directory_is_lost_goes_on_from_its_snapshots_with_a_fresh_optimizer(bag_glob, unbroken_run,
                                                                                           tmp_path):
    """--snapshots keeps fp16 weights and the run and schedule state after every epoch (no optimizer state): with
    the run directory gone (a new machine), --resume goes on after the snapshot's epoch and keeps its metrics."""
    cache, snapshots = str(unbroken_run / "cache"), tmp_path / "snapshots"
    first = ["--bags", bag_glob, "--cache-dir", cache, "--snapshots", str(snapshots), *RESUMABLE]
    main([*first[:-1], "1", "--out", str(tmp_path / "lost")])  # one epoch, then the machine is lost
    snapshot = load_checkpoint(snapshots / "last.pt", with_training_state=True)
    assert snapshot.training_state["epoch"] == 1 and "optimizer" not in snapshot.training_state
    assert (snapshots / "best.pt").read_bytes() == (snapshots / "last.pt").read_bytes()  # epoch 0 is the best so far
    assert (snapshots / "last.pt").stat().st_size < 0.6 * (tmp_path / "lost" / "last.pt").stat().st_size
    main([*first, "--out", str(tmp_path / "new_machine"), "--resume"])
    rows = _rows(tmp_path / "new_machine")
    assert [row["epoch"] for row in rows] == ["0", "1"]  # epoch 0 as the lost run logged it, then epoch 1
    assert _rows(snapshots) == rows
    ended = load_checkpoint(snapshots / "last.pt", with_training_state=True)
    assert ended.training_state["epoch"] == 2 and ended.training_state["steps"] == 2 * snapshot.training_state["steps"]
    resumed = _weights(tmp_path / "new_machine" / "last.pt")
    started = _weights(snapshots / "best.pt") if float(rows[1]["val_total"]) >= float(rows[0]["val_total"]) else None
    assert started is None or any(not torch.equal(resumed[name], started[name]) for name in resumed)  # it trained


def test_the_cosine_schedule_trains_each_epoch_at_its_rate_also_resumed_from_a_plateau_snapshot(bag_glob,
                                                                                             unbroken_run, tmp_path):
    """--schedule cosine: epoch e of E at 3e-4 * (1 + cos(pi e / E)) / 2, in metrics.csv as the epoch trained; a run
    resumed from a snapshot saved under the plateau schedule (a new machine) is put at its epoch's rate, and a
    plateau run refuses the cosine run's state in one line."""
    cache, snapshots = str(unbroken_run / "cache"), tmp_path / "snapshots"
    common = ["--bags", bag_glob, "--cache-dir", cache, "--snapshots", str(snapshots), *RESUMABLE[:-2]]
    main([*common, "--epochs", "1", "--out", str(tmp_path / "lost")])  # epoch 0 under the plateau schedule
    main([*common, "--epochs", "3", "--schedule", "cosine", "--out", str(tmp_path / "new_machine"), "--resume"])
    rates = [float(row["lr"]) for row in _rows(tmp_path / "new_machine")]
    assert rates == pytest.approx([3e-4, 3e-4 * 0.75, 3e-4 * 0.25])  # (1 + cos(pi e / 3)) / 2
    with pytest.raises(SystemExit, match="another schedule than plateau"):
        main([*common, "--epochs", "4", "--out", str(tmp_path / "plateau"), "--resume"])


# --- one recording: validation frames held out of the training bags (--val-fraction) -------------------------------
def test_held_out_blocks_are_spread_over_each_bag_and_about_the_fraction_asked():
    from msfsu_perception.training_data import validation_blocks

    # a 10-minute bag at 10 Hz and a 4-second one: 60 blocks of 10 s, of which every fifth; the short bag: 5 blocks
    stamps = np.concatenate([np.arange(6000) * 100_000_000, 7 * 10**12 + np.arange(40) * 100_000_000])
    bag_of_row = np.repeat([0, 1], [6000, 40])
    held = validation_blocks(stamps, bag_of_row, 0.2)
    long, short = held[:6000], held[6000:]
    assert long.sum() == 1200 and short.sum() == 8  # 12 of 60 blocks, 1 of 5
    starts = np.flatnonzero(np.diff(long.astype(int)) == 1) + 1  # where each held-out block begins
    assert list(starts) == [400 + 500 * k for k in range(12)] and long[-100:].all()  # blocks 4, 9, ..., 59
    assert list(np.flatnonzero(short)) == list(range(32, 40))  # the short bag's last fifth
    assert not validation_blocks(stamps, bag_of_row, 0.2, block_s=1e9)[:4800].any()  # 5 blocks: the last fifth only


def test_one_training_bag_trains_with_held_out_validation_frames(tmp_path, capsys):
    write_synthetic_bag(tmp_path / "bags" / "only", 30, "train", seed=1)
    run = tmp_path / "run"
    main(["--bags", str(tmp_path / "bags" / "*"), "--out", str(run), "--cache-dir", str(tmp_path / "cache"),
          "--val-fraction", "0.2", "--epochs", "1", "--preset", "cpu", "--batch-size", "2", "--num-threads", "1",
          "--max-steps", "2"])
    assert "--val-fraction 0.2: 6 of 30 frames held out for validation" in capsys.readouterr().out
    checkpoint = load_checkpoint(run / "best.pt")
    assert checkpoint.training["val_fraction"] == 0.2 and checkpoint.training["val_bags"] == []
    assert float(_rows(run)[0]["val_total"]) > 0  # validated on the held-out frames


def test_held_out_rows_are_never_training_rows(tmp_path):
    from msfsu_perception.frame_cache import CacheSpec, open_cache
    from msfsu_perception.preprocessing import PreprocessConfig
    from msfsu_perception.training_data import Split, hold_out

    for name, frames in (("a", 30), ("b", 12)):
        write_synthetic_bag(tmp_path / name, frames, "train", seed=len(name))
    spec = CacheSpec((tmp_path / "a", tmp_path / "b"), BagTopics(), PreprocessConfig(32, 32), with_labels=True)
    cache = open_cache(spec, tmp_path / "cache")
    train, validation = hold_out(Split(cache, cache.valid_rows), 0.25)
    assert set(train.rows).isdisjoint(validation.rows) and len(train.rows) + len(validation.rows) == 42
    # the last of 4 equal time blocks of each bag: frames from 3/4 of its span on (a: 21.75 of 29 intervals, b: 8.25
    # of 11; b's rows follow a's 30)
    assert list(validation.rows) == list(range(22, 30)) + list(range(39, 42))


@pytest.mark.parametrize("given, message", [
    ([], "need validation bags, found 1 training and 0 validation bags: import or collect one with split "
         "'validation' (or name it with --val-bags), or hold out a share of the training bags' frames, e.g. "
         "--val-fraction 0.2"),
    (["--val-fraction", "0.2", "--val-bags", "VAL"], "--val-fraction holds validation frames out of the training "
                                                      "bags, but there are 1 validation bags too"),
])
def test_without_validation_bags_or_with_both_sources_of_validation_the_message_says_what_to_do(bag_glob, tmp_path,
                                                                                               given, message):
    train_bag = bag_glob.replace("*", "train")
    given = [bag_glob.replace("*", "validation") if item == "VAL" else item for item in given]
    with pytest.raises(SystemExit) as stopped:
        main(["--train-bags", train_bag, "--out", str(tmp_path / "run"), "--cache-dir", str(tmp_path / "cache"),
              *given, *SMOKE])
    assert str(stopped.value).startswith("msfsu-train: ") and message in str(stopped.value)
    with pytest.raises(SystemExit):
        parse_args(["--bags", "b", "--out", "o", "--val-fraction", "1.0"])


def test_a_bag_without_class_ids_is_one_line_naming_the_variant_that_trains_without(tmp_path):
    bags = tmp_path / "bags"
    write_synthetic_bag(bags / "train", 6, "train", topics=BagTopics(semantic_ids="/elsewhere/class_ids"))
    write_synthetic_bag(bags / "validation", 6, "validation")
    result = subprocess.run([os.path.join(os.path.dirname(sys.executable), "msfsu-train"), "--bags",
                             str(bags / "*"), "--out", str(tmp_path / "run"), "--cache-dir", str(tmp_path / "cache"),
                             *SMOKE], capture_output=True, text=True, timeout=300)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    [line] = result.stderr.strip().splitlines()
    assert line.startswith(f"msfsu-train: bag {(bags / 'train').resolve()} lacks topics "
                           "['/carla/ego_vehicle/semantic_front/class_ids'] (topics: ")
    assert "/elsewhere/class_ids" in line and line.endswith("train --variant msf, which needs none, or record "
                                                             "(import) the bag with its semantic camera")
