"""The lateral study: command runs and turn onsets, the cluster bootstrap, steer errors of networks whose answer is
known (constant policies) on a synthetic bag, the gradient share, the record's round trip and the command line."""

import numpy as np
import pytest

from msfsu_common.road_option import RoadOption
from msfsu_evaluation import lateral_study
from msfsu_evaluation.lateral_study import FrameGroups, cluster_bootstrap, command_runs, turn_onset
from msfsu_evaluation.records.lateral_study import PAGE_NAME, RECORD_NAME, LateralStudy
from msfsu_perception.synthetic import write_synthetic_bag


def test_command_runs_are_the_maximal_runs_of_one_value():
    assert command_runs(np.array([4, 4, 1, 1, 1, 4, 2], np.uint8)) == [(0, 2), (2, 5), (5, 6), (6, 7)]
    assert command_runs(np.array([], np.uint8)) == []


def test_a_left_turn_begins_where_the_expert_first_steers_half_its_peak_to_the_left():
    steer = np.array([0.0, -0.01, 0.05, -0.1, -0.3, -0.4, -0.2])  # right is positive: the peak left is -0.4
    assert turn_onset(steer, RoadOption.LEFT) == 4  # -0.3 is the first at or past -0.2
    assert turn_onset(-steer, RoadOption.RIGHT) == 4
    assert turn_onset(np.array([0.1, 0.2]), RoadOption.LEFT) == 2  # never steers left: all approach


def test_the_cluster_bootstrap_resamples_whole_runs():
    values = np.array([1.0, 1.0, 1.0, 3.0])
    # one cluster: every resample is the same mean
    assert cluster_bootstrap(values, np.zeros(4, np.int64)) == pytest.approx((1.5, 1.5))
    # two clusters of unequal size: the means a resample can give are 1, 3 and the pooled 1.5
    low, high = cluster_bootstrap(values, np.array([0, 0, 0, 1]))
    assert low == pytest.approx(1.0) and high == pytest.approx(3.0)


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("lateral") / "bag"
    write_synthetic_bag(path, n_frames=48, split="test", seed=3, noise_period_frames=1000)
    return path


def test_constant_policies_get_the_errors_their_answers_give(bag, constant_policy_checkpoint, tmp_path):
    left, right = constant_policy_checkpoint(-0.2, 5.0), constant_policy_checkpoint(0.1, 5.0)
    out = tmp_path / "study"
    assert lateral_study.main(["--bags", str(bag), "--network", f"left={left}:torch/fp32",
                               "--network", f"right={right}:torch/fp32", "--reference", "right", "--branches",
                               "--cache-dir", str(tmp_path / "cache"), "--threads", "1", "--out", str(out)]) == 0
    study = LateralStudy.from_json((out / RECORD_NAME).read_text())
    assert study.networks["left"]["runtime"] == "torch/fp32"
    rows = {(r.network, r.group): r for r in study.steer}
    groups = {r.group for r in study.steer}
    assert "all" in groups and groups & {"LEFT approach", "LEFT turn", "RIGHT approach", "RIGHT turn"}
    for group in groups:
        a, b = rows["left", group], rows["right", group]
        assert a.frames == b.frames and a.runs >= 1
        assert a.signed - b.signed == pytest.approx(-0.3, abs=1e-5)  # the same frames, answers 0.3 apart
        assert a.signed_ci95[0] <= a.signed <= a.signed_ci95[1] and a.mae_ci95[0] <= a.mae <= a.mae_ci95[1]
    for paired in study.paired:
        assert (paired.network, paired.reference) == ("left", "right")
        assert paired.signed_difference == pytest.approx(-0.3, abs=1e-5)
        assert paired.signed_difference_ci95 == pytest.approx((-0.3, -0.3), abs=1e-5)
    # a constant policy's every branch answers the same: each branch's error on an approach is the group's error
    assert {b.group for b in study.branches} <= set(lateral_study.BRANCH_GROUPS) and study.branches
    for b in study.branches:
        assert b.signed == pytest.approx(rows[b.network, b.group].signed, abs=1e-6)
    assert len({b.branch for b in study.branches}) == len(RoadOption)
    page = (out / PAGE_NAME).read_text()
    assert page == study.markdown() and "## Paired with right on the same frames" in page
    assert "## Every branch on the turn approaches" in page
    (out / PAGE_NAME).unlink()
    assert lateral_study.main(["--render", str(out)]) == 0 and (out / PAGE_NAME).read_text() == page


def test_frame_groups_split_each_turn_run_at_its_onset(bag, tiny_checkpoint, tmp_path):
    from msfsu_evaluation.deploy.scoring import load_held_out
    from msfsu_perception.bag_topics import BagTopics
    from msfsu_perception.checkpoint import load_checkpoint

    [held_out] = load_held_out([bag], BagTopics(), load_checkpoint(tiny_checkpoint).preprocess, tmp_path / "cache")
    groups = FrameGroups.of([held_out])
    command = held_out.truth.command[held_out.indices]
    for start, stop in command_runs(command):
        option = RoadOption(int(command[start]))
        names = groups.group[start:stop]
        assert len(set(groups.cluster[start:stop])) == 1
        if option in (RoadOption.LEFT, RoadOption.RIGHT):
            onset = start + turn_onset(held_out.steer[start:stop], option)
            assert set(names[:onset - start]) <= {f"{option.name} approach"}
            assert set(names[onset - start:]) <= {f"{option.name} turn"}
        else:
            assert set(names) == {option.name}


def test_the_gradient_share_compares_the_two_losses_on_the_encoder(bag, tiny_checkpoint, tmp_path):
    from msfsu_evaluation.deploy.scoring import load_held_out
    from msfsu_perception.bag_topics import BagTopics
    from msfsu_perception.checkpoint import load_checkpoint

    bags = load_held_out([bag], BagTopics(), load_checkpoint(tiny_checkpoint).preprocess, tmp_path / "cache")
    shares = lateral_study.gradient_share(tiny_checkpoint, "tiny", bags, batch_size=16)
    assert [s.frames_of for s in shares][0] == "all" and shares[0].frames == len(bags[0])
    for share in shares:
        assert share.control_norm > 0 and share.scene_norm > 0
        assert share.ratio == pytest.approx(share.scene_norm / share.control_norm)
        assert -1.0 <= share.cosine <= 1.0


def test_a_network_without_a_decoder_has_no_gradient_share(bag, tiny_checkpoint, tmp_path):
    from msfsu_perception.checkpoint import load_checkpoint, save_checkpoint
    from msfsu_perception.model import MSFSUConfig, build_model

    loaded = load_checkpoint(tiny_checkpoint)
    config = MSFSUConfig.from_dict({**loaded.model.config.to_dict(), "variant": "msf"})
    path = tmp_path / "msf.pt"
    save_checkpoint(path, build_model(config), loaded.preprocess)
    assert lateral_study.gradient_share(path, "msf", []) == []


@pytest.mark.parametrize("argv, message", [
    (["--bags", "nowhere", "--network", "a=models/msf.pt", "--out", "x"], "not a rosbag2 bag"),
    (["--network", "nameless"], "expected NAME=CHECKPOINT"),
])
def test_a_user_error_is_one_line(argv, message, capsys):
    try:
        code = lateral_study.main(argv)
    except SystemExit as exit_:
        code = exit_.code
    assert code == 2
    error = capsys.readouterr().err
    assert message in error and "Traceback" not in error


def test_the_verdict_says_only_what_the_intervals_show():
    from msfsu_evaluation.records.lateral_study import PairedSteer, verdict

    def row(mae, signed):
        return PairedSteer("a", "b", "LEFT approach", 10, 0.0, mae, 0.0, signed)

    assert verdict(row((0.01, 0.02), (-0.03, -0.01))) == "errs more, left of b"
    assert verdict(row((-0.02, -0.01), (0.01, 0.03))) == "errs less, right of b"
    assert verdict(row((-0.01, 0.02), (-0.01, 0.01))) == "no difference shown"
    assert verdict(row((-0.01, 0.02), (0.001, 0.01))) == "right of b"


def test_the_own_command_answer_picked_from_every_branch_is_the_frames_prediction(bag, tiny_checkpoint, tmp_path):
    from msfsu_evaluation.deploy.scoring import load_held_out, predict_held_out
    from msfsu_perception.bag_topics import BagTopics
    from msfsu_perception.inference import DrivingModel

    model = DrivingModel.from_checkpoint(tiny_checkpoint, 1)
    bags = load_held_out([bag], BagTopics(), model.preprocess, tmp_path / "cache")
    picked = lateral_study.own_command_steer(lateral_study.branch_predictions(model, bags), bags)
    np.testing.assert_allclose(picked, predict_held_out(model, bags[0]).steer, atol=1e-6)
