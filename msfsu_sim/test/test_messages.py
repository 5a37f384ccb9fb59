"""Frame messages of the simulator: class ids are published only when the semantic pass renders them."""

import numpy as np

from msfsu_common import bag_io, topics
from msfsu_common.road_option import RoadOption
from msfsu_sim.environment import Observation, Odometry
from msfsu_sim.messages import rosbags_builder


def _observation(ids: np.ndarray | None) -> Observation:
    return Observation(step=3, time_s=0.3, rgb=np.zeros((4, 6, 3), np.uint8), depth=np.ones((4, 6), np.float32),
                       semantic_ids=ids, odometry=Odometry(1.0, 2.0, 0.1, 3.0, 0.0),
                       command=RoadOption.LANE_FOLLOW, route_progress_m=1.0, route_completion=0.1,
                       collision=False, out_of_road=False, arrived=False)


def test_evaluation_frames_carry_no_class_ids_and_collection_frames_do():
    build = rosbags_builder(bag_io.msfsu_typestore())
    without = build.sensors(_observation(None))
    with_ids = build.sensors(_observation(np.full((4, 6), 2, np.uint8)))
    assert topics.SEMANTIC_IDS not in without and {topics.RGB, topics.DEPTH, topics.ODOMETRY} <= without.keys()
    image = with_ids[topics.SEMANTIC_IDS]
    assert (image.encoding, image.width, image.height) == ("mono8", 6, 4)
    assert set(bytes(image.data)) == {2}


def test_the_route_as_the_bridges_waypoints_is_a_path_of_its_poses_without_options():
    from msfsu_sim.route import Route

    route = Route(poses=np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [5.0, 5.0, np.pi / 2]]),
                  options=np.array([RoadOption.LANE_FOLLOW, RoadOption.LEFT, RoadOption.LANE_FOLLOW], np.uint8))
    path = rosbags_builder(bag_io.msfsu_typestore()).path(1.5, route)
    assert path.__msgtype__ == "nav_msgs/msg/Path" and path.header.frame_id == "map"
    assert [(pose.pose.position.x, pose.pose.position.y) for pose in path.poses] == [(0.0, 0.0), (5.0, 0.0), (5.0, 5.0)]
    assert all((pose.header.stamp.sec, pose.header.stamp.nanosec) == (1, 500_000_000) for pose in path.poses)
    assert path.poses[2].pose.orientation.z == np.sin(np.pi / 4)
