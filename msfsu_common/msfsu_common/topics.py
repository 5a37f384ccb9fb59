"""Default topic names of the graph.

Sensors follow carla-ros-bridge (`/carla/<role>/<sensor>/...`) so a CARLA user only remaps nothing;
the stack's own messages live under `/msfsu/`.
"""

ROLE = "ego_vehicle"


def carla_topic(name: str, role: str = ROLE) -> str:
    """carla-ros-bridge's topic `name` of the ego vehicle `role`: /carla/<role>/<name>."""
    return f"/carla/{role}/{name}"


# the sensor ids of the bridge's example sensor file (carla_spawn_objects/config/objects.json): a camera publishes
# /carla/<role>/<sensor id>/image
RGB_SENSOR = "rgb_front"
DEPTH_SENSOR = "depth_front"
SEMANTIC_SENSOR = "semantic_segmentation_front"

RGB = carla_topic(f"{RGB_SENSOR}/image")
DEPTH = carla_topic(f"{DEPTH_SENSOR}/image")
SEMANTIC_IDS = carla_topic("semantic_front/class_ids")
ODOMETRY = carla_topic("odometry")
CLOCK = "/clock"
# what the bridge itself takes and sends beside the sensors: the control it applies to the car
# (carla_msgs/CarlaEgoVehicleControl), the car's own status (CarlaEgoVehicleStatus) and the route its waypoint
# publisher planned (nav_msgs/Path, latched)
CARLA_VEHICLE_CONTROL = carla_topic("vehicle_control_cmd")
CARLA_VEHICLE_STATUS = carla_topic("vehicle_status")
WAYPOINTS = carla_topic("waypoints")

NAVIGATION_COMMAND = "/msfsu/navigation_command"
# where the simulator's own (ground-truth) command goes when the route node gives the graph's command
# (profiles/sim.yaml remaps sim_bridge to it; a test checks the profile)
SIM_NAVIGATION_COMMAND = "/msfsu/sim/navigation_command"
ROUTE = "/msfsu/route"
DRIVING_ACTION = "/msfsu/driving_action"
# the network's own DrivingAction where the emergency brake (aeb node) sits between perception and control: profiles
# with aeb on remap perception's DRIVING_ACTION here, and the aeb node publishes DRIVING_ACTION
NETWORK_ACTION = "/msfsu/network/driving_action"
AEB_INTERVENTION = "/msfsu/aeb/intervention"
EXPERT_ACTION = "/msfsu/expert/driving_action"
VEHICLE_CONTROL = "/msfsu/vehicle_control"
SEGMENTATION = "/msfsu/segmentation"
SEGMENTATION_OVERLAY = "/msfsu/segmentation/overlay"
# 32FC1 metres: the camera's depth at the centre of each pixel of the segmentation (same stamp and size), published by
# perception after the action and before the segmentation, for the emergency brake (aeb node)
SEGMENTATION_DEPTH = "/msfsu/segmentation/depth"
NOISE_INJECTION = "/msfsu/noise_injection"
# msfsu-collect: std_msgs/Bool per frame, True when the network's action drove it (on-policy rounds)
NETWORK_DRIVING = "/msfsu/network_driving"
# msfsu-collect: std_msgs/String per frame, what held the expert's label below its desired speed (bag_io.EXPERT_LIMITS)
EXPERT_LIMITED_BY = "/msfsu/expert/limited_by"
DIAGNOSTICS = "/diagnostics"
# msfsu_interfaces/StageTimes of every traced frame, from nodes whose publish_stage_times is true (latency tracing)
STAGE_TIMES = "/msfsu/stage_times"
# every node that keeps state from frame to frame offers this service (std_srvs/Trigger, msfsu_common.reset): it
# forgets that state, as at its start; the closed-loop benchmark calls it on each node before every episode
RESET_SERVICE = "~/reset"
