"""The emergency brake's core (msfsu_control.aeb) on hand-made frames: a box standing in front of the camera, drawn
into the network's crop as vehicle_or_pedestrian with its depth, everything else road far away."""

import math

import numpy as np
import pytest

from msfsu_common.camera_geometry import CameraView, depth_at_crop_pixels
from msfsu_common.semantic_classes import SemanticClass
from msfsu_control.aeb import (BRAKE, CAP, NONE, AebConfig, Cluster, EmergencyBrake, corridor_arc, crossing,
                               find_obstacle, invalid_depth_fraction, to_car, to_world)

CAMERA = CameraView(400, 300, 1.0, 0.0, 2.095, -2.0, 80.0, 0.5, 0, 0)  # the simulator's front camera
SEG = (128, 128)
CONFIG = AebConfig()


def camera_frame(boxes=(), road_label=False):
    """(labels, depth) at the camera's size of a scene of upright boxes (forward, right, width, height:
    their face towards the car, metres from the car's centre on the ground). road_label: the road below the horizon
    labelled vehicle_or_pedestrian too (a mislabelled patch of asphalt)."""
    depth = np.full((CAMERA.height, CAMERA.width), 80.0, np.float32)
    columns, rows = np.meshgrid(np.arange(CAMERA.width) + 0.5, np.arange(CAMERA.height) + 0.5)
    pitch = math.radians(CAMERA.pitch_deg)
    up_n = -(rows - CAMERA.height / 2) / CAMERA.focal_px  # up per metre of depth, camera frame
    forward_per_depth = math.cos(pitch) - up_n * math.sin(pitch)
    height_per_depth = math.sin(pitch) + up_n * math.cos(pitch)
    labels = np.zeros(depth.shape, np.uint8)
    if road_label:  # where each ray below the horizon meets the road
        ground = np.where(height_per_depth < -1e-3, -CAMERA.up_m / np.minimum(height_per_depth, -1e-3), np.inf)
        depth = np.where(np.isfinite(ground), np.minimum(ground, 80.0), depth).astype(np.float32)
        labels[np.isfinite(ground) & (ground < 30)] = SemanticClass.VEHICLE_OR_PEDESTRIAN
    for forward, right, width, height in boxes:
        d = (forward - CAMERA.forward_m) / forward_per_depth
        across = (columns - CAMERA.width / 2) / CAMERA.focal_px * d + CAMERA.right_m
        up = height_per_depth * d + CAMERA.up_m
        hit = (d > 0) & (d < depth) & (np.abs(across - right) <= width / 2) & (up >= 0) & (up <= height)
        depth[hit] = d[hit]
        labels[hit] = SemanticClass.VEHICLE_OR_PEDESTRIAN
    return labels, depth


def crop_pixels():
    """The camera pixel the centre of each segmentation pixel falls in (an index of camera_frame's arrays)."""
    top = int(CAMERA.height * CAMERA.crop_top_fraction)
    crop_rows = (top + (np.arange(SEG[0]) + 0.5) * (CAMERA.height - top) / SEG[0]).astype(int)
    crop_columns = ((np.arange(SEG[1]) + 0.5) * CAMERA.width / SEG[1]).astype(int)
    return np.ix_(crop_rows, crop_columns)


def frame(boxes=(), road_label=False):
    """(segmentation at SEG, the depth at its pixels) of the scene of camera_frame: what perception publishes."""
    labels, depth = camera_frame(boxes, road_label)
    return labels[crop_pixels()], depth[crop_pixels()]


def test_the_depth_at_the_segmentation_pixels_is_the_camera_pixel_each_centre_falls_in():
    _, depth = camera_frame([(6.0, 0.5, *PEDESTRIAN)])
    np.testing.assert_array_equal(depth_at_crop_pixels(depth, CAMERA.crop_top_fraction, SEG), depth[crop_pixels()])
    assert depth_at_crop_pixels(depth, 0.5, (3, 4)).shape == (3, 4)


PEDESTRIAN = (0.6, 1.8)  # width, height


def test_a_pedestrian_ahead_is_found_at_its_gap_from_the_bumper():
    seg, depth = frame([(10.0, 0.0, *PEDESTRIAN)])
    found = find_obstacle(seg, depth, CAMERA, 0.0, 5.0, CONFIG)
    assert found is not None and found.gap_m == pytest.approx(10.0 - CONFIG.front_m, abs=0.3)
    assert abs(found.lateral_m) < 0.4 and found.pixels >= CONFIG.min_pixels


@pytest.mark.parametrize("right, inside", [(1.0, True), (1.6, True), (2.2, False), (-2.2, False), (3.5, False)])
def test_the_corridor_is_the_cars_width_plus_the_margin(right, inside):
    """Half width 1.0 + margin 0.4: a pedestrian 0.3 m wide whose near side is within 1.4 m of the centre line is in;
    one in the next lane (3.5 m) is not. Edge: its near side at 1.6 - 0.3 = 1.3 m is in, at 1.9 m it is not."""
    seg, depth = frame([(12.0, right, *PEDESTRIAN)])
    assert (find_obstacle(seg, depth, CAMERA, 0.0, 5.0, CONFIG) is not None) == inside


def test_beyond_the_horizon_of_the_corridor_nothing_counts_and_the_reach_grows_with_speed():
    seg, depth = frame([(25.0, 0.0, *PEDESTRIAN)])
    assert find_obstacle(seg, depth, CAMERA, 0.0, 2.0, CONFIG) is None  # 2.3 + max(6, 6) m of corridor
    assert find_obstacle(seg, depth, CAMERA, 0.0, 8.0, CONFIG) is not None  # 8 m/s x 3 s


def test_a_curved_corridor_follows_the_steer():
    """A pedestrian 8.5 m ahead and 3.5 m to the right is outside a straight corridor but on the path of a car
    steering right (steer 0.3: radius 11.8 m, 45 degrees round the turn), and not in the one of a car steering left."""
    seg, depth = frame([(8.5, 3.5, *PEDESTRIAN)])
    assert find_obstacle(seg, depth, CAMERA, 0.0, 6.0, CONFIG) is None
    assert find_obstacle(seg, depth, CAMERA, 0.3, 6.0, CONFIG) is not None
    assert find_obstacle(seg, depth, CAMERA, -0.3, 6.0, CONFIG) is None
    arc, lateral = corridor_arc(np.array([10.0]), np.array([0.0]), 1 / 20.0)
    assert arc[0] == pytest.approx(20 * math.atan2(10, 20)) and lateral[0] == pytest.approx(20 - math.hypot(10, 20))


def test_road_labelled_as_an_obstacle_and_nan_depth_are_not_obstacles():
    seg, depth = frame(road_label=True)
    assert (seg == SemanticClass.VEHICLE_OR_PEDESTRIAN).sum() > 1000
    assert find_obstacle(seg, depth, CAMERA, 0.0, 8.0, CONFIG) is None  # points on the road: below min_height
    seg, depth = frame([(8.0, 0.0, *PEDESTRIAN)])
    depth[:] = np.nan
    assert find_obstacle(seg, depth, CAMERA, 0.0, 8.0, CONFIG) is None
    assert invalid_depth_fraction(depth) == 1.0


def drive(brake, frames, speed=5.0, target=6.0, start=0.0):
    """Feed (segmentation, depth) frames at 10 Hz; the decisions."""
    return [brake.step(start + 0.1 * i, target, 0.0, speed, seg, depth, CAMERA) for i, (seg, depth) in enumerate(frames)]


def test_it_brakes_for_a_close_pedestrian_caps_for_a_farther_one_and_lets_go_after_the_release_time():
    brake = EmergencyBrake()
    near = frame([(4.0, 0.0, *PEDESTRIAN)])  # 1.7 m from the bumper
    clear = frame()
    decisions = drive(brake, [near] * 3 + [clear] * 15, speed=1.0)
    assert [d.kind for d in decisions[:3]] == [BRAKE] * 3 and decisions[0].target_speed == 0.0
    assert decisions[0].reason == "obstacle within the stop gap"
    kinds = [d.kind for d in decisions[3:]]
    assert kinds[:9] == [BRAKE] * 9 and kinds[10] == NONE  # held for release_s (1 s) of clear corridor
    assert decisions[-1].target_speed == 6.0
    farther = frame([(13.0, 0.0, *PEDESTRIAN)])  # 10.7 m at 8 m/s: 1.3 s to collision, more than its stopping distance
    capped = EmergencyBrake().step(0.0, 8.0, 0.0, 8.0, *farther, CAMERA)
    assert capped.kind == CAP and 0 < capped.target_speed < 8.0
    assert capped.target_speed == pytest.approx(math.sqrt(2 * CONFIG.cap_decel * (capped.gap_m - CONFIG.stop_gap_m)))
    far = frame([(20.0, 0.0, *PEDESTRIAN)])  # 17.7 m: the cap (9.7 m/s) is above the 8 m/s asked for, no intervention
    assert EmergencyBrake().step(0.0, 8.0, 0.0, 8.0, *far, CAMERA).kind == NONE


def test_a_lead_driving_at_the_cars_speed_is_let_go_once_its_gap_is_seen_not_to_close():
    """12 m ahead at 8 m/s a standing obstacle is a cap (its gap unknown to change, the first frames judge it so); a
    lead holding that gap closes at 0 m/s: no time to collision, and the cap goes after release_s."""
    lead = [frame([(12.0, 0.0, 1.9, 1.5)])] * 25
    decisions = drive(EmergencyBrake(), lead, speed=8.0, target=8.0)
    assert decisions[0].kind == CAP
    assert decisions[-1].kind == NONE and decisions[-1].ttc_s == math.inf and decisions[-1].target_speed == 8.0


def test_frames_it_cannot_judge_are_counted_the_decision_is_held_then_the_action_passes():
    brake = EmergencyBrake()
    near = frame([(4.0, 0.0, *PEDESTRIAN)])
    assert brake.step(0.0, 6.0, 0.0, 2.0, *near, CAMERA).kind == BRAKE
    held = brake.step(0.1, 6.0, 0.0, 2.0, None, near[1], CAMERA)
    assert (held.kind, held.target_speed, held.dropped) == (BRAKE, 0.0, "no_segmentation")
    nan_depth = np.full_like(near[1], np.nan)
    assert brake.step(0.3, 6.0, 0.0, 2.0, near[0], nan_depth, CAMERA).dropped == "invalid_depth"
    passed = brake.step(0.7, 6.0, 0.0, 2.0, near[0], None, CAMERA)  # 0.7 s after the last judged frame
    assert (passed.kind, passed.target_speed, passed.dropped) == (NONE, 6.0, "no_depth")
    assert brake.drops == {"no_segmentation": 1, "no_depth": 1, "bad_segmentation": 0, "invalid_depth": 1}


CROSSING = AebConfig()  # the default predicts crossings
CORRIDOR = AebConfig(predict_crossing=False)


def walk(config, pedestrian, velocity, ego_speed=1.5, target=4.0, ego_yaw_rate=0.0, seconds=2.0):
    """The car drives from the origin along x at `ego_speed` (turning at `ego_yaw_rate`, rad/s counter-clockwise)
    asking for `target`; a pedestrian starts at world `pedestrian` (x, y: y left) and walks at `velocity`. 10 Hz frames
    -> the decisions and the pedestrian's (forward, right) in the car's frame at each."""
    brake, x, y, yaw = EmergencyBrake(config), 0.0, 0.0, 0.0
    decisions, seen = [], []
    for i in range(int(seconds * 10)):
        t = 0.1 * i
        px, py = pedestrian[0] + velocity[0] * t, pedestrian[1] + velocity[1] * t
        forward = (px - x) * math.cos(yaw) + (py - y) * math.sin(yaw)
        right = (px - x) * math.sin(yaw) - (py - y) * math.cos(yaw)
        seg, depth = frame([(forward, right, *PEDESTRIAN)])
        decisions.append(brake.step(t, target, 0.0, ego_speed, seg, depth, CAMERA, (x, y, yaw)))
        seen.append((forward, right))
        x, y, yaw = x + ego_speed * 0.1 * math.cos(yaw), y + ego_speed * 0.1 * math.sin(yaw), yaw + ego_yaw_rate * 0.1
    return decisions, seen


def test_frames_of_the_car_and_of_the_odometry_convert_both_ways():
    pose = (3.0, -2.0, 0.7)
    x, y = to_world(pose, 5.0, 1.5)
    forward, right = to_car(pose[2], x - pose[0], y - pose[1])  # a point is a displacement from the car
    assert (forward, right) == (pytest.approx(5.0), pytest.approx(1.5))
    assert to_world((0.0, 0.0, 0.0), 1.0, 1.0) == (1.0, -1.0)  # right is -y


def test_a_pedestrian_walking_into_the_path_is_capped_for_before_it_is_in_the_corridor():
    """The held-out collision the route run showed: a pedestrian 3.5 m right of the path and 7 m ahead walks in at
    1.2 m/s while the car asks for 4 m/s. Without the prediction nothing happens until it is in the corridor; with it,
    while the pedestrian is still 2 m or more beside the path, the car is capped to a speed at which it comes within
    the stop gap of the pedestrian's line only after the pedestrian has crossed the corridor."""
    decisions, seen = walk(CORRIDOR, (7.0, -3.5), (0.0, 1.2))
    outside = [d for d, (_, right) in zip(decisions, seen) if right > 2.0]
    assert len(outside) >= 10 and all(d.kind == NONE for d in outside)
    decisions, seen = walk(CROSSING, (7.0, -3.5), (0.0, 1.2))
    first = next(i for i, d in enumerate(decisions) if d.kind != NONE)
    assert seen[first][1] > 2.0 and decisions[first].reason == "crossing into the corridor"
    cap, gap = decisions[first].target_speed, decisions[first].gap_m
    crossed_s = (seen[first][1] + CONFIG.half_width_m + CONFIG.margin_m) / 1.2
    assert decisions[first].kind == CAP and (gap - CONFIG.stop_gap_m) / cap == pytest.approx(crossed_s, rel=0.25)
    assert decisions[first].gap_m == pytest.approx(seen[first][0] - CONFIG.front_m, abs=0.5)
    assert EmergencyBrake(CROSSING).step(0.0, 4.0, 0.0, 1.5, *frame([(7.0, 3.5, *PEDESTRIAN)]), CAMERA).kind == NONE


@pytest.mark.parametrize("velocity, yaw_rate", [((1.2, 0.0), 0.0), ((0.0, -1.2), 0.0), ((0.0, 0.0), -0.3)],
                         ids=["walking along the path", "walking away from it", "standing while the car turns"])
def test_a_pedestrian_not_crossing_is_left_alone(velocity, yaw_rate):
    """Beside the path walking along it or away, or standing while the car turns right towards it (in the car's frame
    it comes in at 0.3 rad/s x 8 m; in the world it stands): no intervention while it is beside the corridor."""
    decisions, seen = walk(CROSSING, (8.0, -3.5), velocity, ego_yaw_rate=yaw_rate, seconds=1.5)
    beside = [d for d, (_, right) in zip(decisions, seen) if abs(right) > 2.0]
    assert len(beside) >= 6 and all(d.kind == NONE for d in beside)


def test_a_patch_seen_in_scattered_frames_moves_nothing():
    """The phantom the route run showed (a few pixels 20 m ahead and 4 m beside the path, seen in two frames, lost for
    two, seen again, at cruise speed): each sighting after a gap longer than track_lost_s starts a new track, none is
    followed long enough to have a speed, so nothing acts; the same patch seen in every frame and moving in is capped
    for."""
    def drive(seen_at):
        brake, decisions = EmergencyBrake(CROSSING), []
        for i in range(20):
            t, x = 0.1 * i, 8.0 * 0.1 * i  # the car at 8 m/s along x; the patch at world (26, 3.5 - 0.8 t)
            boxes = [(26.0 - x, -(3.5 - 0.8 * t), *PEDESTRIAN)] if i in seen_at else []
            decisions.append(brake.step(t, 8.0, 0.0, 8.0, *frame(boxes), CAMERA, (x, 0.0, 0.0)))
        return decisions
    assert all(d.kind == NONE for d in drive({0, 1, 4, 5, 8, 9, 12, 13}))
    assert any(d.reason == "crossing into the corridor" for d in drive(set(range(20))))


@pytest.mark.parametrize("velocity, meets", [((0.0, 1.0), True), ((-7.0, 0.6), False), ((8.0, 1.0), False)],
                         ids=["walking in", "oncoming in the next lane, drifting in", "ahead going the car's way"])
def test_the_obstacles_own_speed_along_the_path_decides_whether_the_car_meets_it(velocity, meets):
    """20 m ahead, 3 m left of the path, coming towards it, the car at 8 m/s: a pedestrian walking in is met; a car in
    the next lane coming the other way is passed in about 1.3 s, long before its drift (0.6 m/s) takes it into the
    corridor (2.7 s); a car ahead going the car's way as fast is never reached."""
    found = crossing(Cluster(22.3, -3.0, 50), velocity, 0.0, 8.0, CROSSING)
    assert (found is not None) == meets
    if meets:
        assert (found.gap_m, found.toward_mps, found.along_mps) == (pytest.approx(20.0), pytest.approx(1.0),
                                                                     pytest.approx(0.0, abs=1e-9))


def test_the_cap_keeps_the_car_short_of_where_a_walker_coming_towards_it_crosses():
    """A pedestrian 3.5 m right of the path and 10 m ahead crosses diagonally towards the car (1.2 m/s across, 1 m/s
    along the path towards it): the cap lets the car cover, by the time the pedestrian has crossed, no more than the
    gap to the point where it leaves the corridor, less the stop gap (within what the cluster's median point and the
    fitted speeds allow); planning for where it is now would let the car run into it."""
    decisions, seen = walk(CROSSING, (10.0, -3.5), (-1.0, 1.2))
    first = next(i for i, d in enumerate(decisions) if d.kind != NONE)
    cap, gap = decisions[first].target_speed, decisions[first].gap_m
    leave = (seen[first][1] + CROSSING.half_width_m + CROSSING.margin_m) / 1.2
    assert decisions[first].reason == "crossing into the corridor" and cap > 0.0
    assert cap * leave <= gap - 1.0 * leave - CROSSING.stop_gap_m + 0.5  # within half a metre of the estimates
    assert (gap - CROSSING.stop_gap_m) / leave > 2 * cap  # the cap of one standing still along the path: far more


def test_a_crossing_the_car_does_not_meet_is_left_alone():
    """Crossing 15 m ahead while the car crawls at 0.3 m/s: it has crossed long before the car arrives."""
    decisions, _ = walk(CROSSING, (15.0, -3.5), (0.0, 1.2), ego_speed=0.3, target=0.3)
    assert all(d.kind == NONE for d in decisions)
