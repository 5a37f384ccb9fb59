"""Traffic and pedestrians of the simulator: awake from the first step, clear of the ego at the start,
seen by MetaDrive's traffic policy, walking where they should (the session's simulator, town_a)."""

import numpy as np
import pytest
from metadrive.policy.idm_policy import FrontBackObjects

from msfsu_sim.clearance import DEFAULT_CLEARANCE, ClearZone, SpawnClearance
from msfsu_sim.environment import RouteSpec
from msfsu_sim.pedestrians import Person
from msfsu_sim.route_catalog import road_routes
from msfsu_sim.scene import PEDESTRIAN
from msfsu_sim.traffic import YIELD_LOOK_M, _first_come_gap, ego_clear_zone, front_gap

NO_CLEARANCE = SpawnClearance(0.0, 0.0, 0.0)


def test_clear_zone_is_a_disc_round_the_ego_and_a_corridor_along_the_route_ahead():
    route = np.stack([np.arange(0.0, 60.0, 1.0), np.zeros(60)], axis=1)
    zone = ClearZone((0.0, 0.0), route, SpawnClearance(radius_m=10.0, route_m=30.0, corridor_half_width_m=2.5))
    assert zone.blocks((8.0, 5.0)) and zone.blocks((25.0, 1.0)) and zone.blocks((25.0, 3.5), radius_m=1.5)
    assert not zone.blocks((25.0, 3.5)) and not zone.blocks((40.0, 0.0)) and not zone.blocks((-12.0, 0.0))


class _Box:
    LENGTH, WIDTH = 4.5, 2.0

    def __init__(self, x, y, heading_rad=0.0):
        self.position = (x, y)
        self.heading = (np.cos(heading_rad), np.sin(heading_rad))


@pytest.mark.parametrize("ego, gap", [
    ((10.0, 0.0), 5.5),  # straight ahead
    ((10.0, 2.4), 5.5),  # bodies overlap across (half widths 1 + 1 + margin 0.5)
    ((10.0, 2.6), None),  # beside its path: the next lane
    ((10.0, -3.5), None),  # oncoming lane
    ((-10.0, 0.0), None),  # behind
    ((YIELD_LOOK_M + 1.0, 0.0), None),  # too far to matter
])
def test_a_traffic_car_sees_the_ego_in_front_of_its_bumper(ego, gap):
    car = _Box(0.0, 0.0)
    assert front_gap(car, _Box(*ego)) == (None if gap is None else pytest.approx(gap))
    turned = _Box(0.0, 0.0, np.pi / 2)  # the same, rotated: the check follows the car's heading, not its lane
    rotated = front_gap(turned, _Box(-ego[1], ego[0]))
    assert rotated == (None if gap is None else pytest.approx(gap))


def _in_zone(sim, clearance):
    zone = ego_clear_zone(sim._env.engine, clearance)
    return [o for o in sim.obstacles() if zone.blocks((o.x, o.y), max(o.length, o.width) / 2)]


class _Car(_Box):
    def __init__(self, x, y, heading_rad=0.0, speed=0.0, id="car"):
        super().__init__(x, y, heading_rad)
        self.velocity = (speed * np.cos(heading_rad), speed * np.sin(heading_rad))
        self.id = id


def test_at_a_junction_the_car_that_gets_to_the_meeting_point_first_goes_first():
    """This car drives east along y = 0 at 5 m/s; its path's point 10 m ahead is where a crossing car
    driving north (x = 10) meets it."""
    me = _Car(0.0, 0.0, 0.0, speed=5.0, id="b")
    path = np.stack([np.arange(1.0, 26.0), np.zeros(25)], axis=1)  # 1 m steps ahead of it
    sooner = _Car(10.0, -3.0, np.pi / 2, speed=5.0, id="x")  # there in ~0.5 s (within reach), me in 2 s
    later = _Car(10.0, -20.0, np.pi / 2, speed=5.0, id="y")  # 3.4 s away: after me
    standing = _Car(10.0, 0.5, np.pi / 2, speed=0.0, id="z")  # stuck on the crossing: already there
    assert _first_come_gap(me, path, sooner) == pytest.approx(8.0 - 4.5)  # stops short of it (bumper gap)
    assert _first_come_gap(me, path, later) is None
    assert _first_come_gap(me, path, standing) is not None
    assert _first_come_gap(me, path, _Car(15.0, 0.0, 0.0, speed=3.0)) is None  # its own direction: IDM's
    # the crossing car sees this one coming later than itself: no yield both ways (no deadlock)
    its_path = np.stack([np.full(25, 10.0), np.arange(-2.0, 23.0)], axis=1)
    assert _first_come_gap(sooner, its_path, me) is None


def test_nothing_spawns_in_the_clear_zone_where_it_otherwise_would(sim):
    """Search the town's route starts for one where dense traffic lands in the zone; the clearance empties it."""
    sim.reset("town_a", "clear_noon", "empty", 0)
    network = sim._env.engine.current_map.road_network
    starts = {route.checkpoints[:2]: route for route in road_routes(network.graph, network.shortest_path)}
    for start, route in sorted(starts.items()):
        spec = RouteSpec(start, 0, 5.0, route.checkpoints[-1])
        sim.reset("town_a", "clear_noon", "dense", 3, spec, clearance=NO_CLEARANCE)
        if _in_zone(sim, DEFAULT_CLEARANCE):
            break
    else:
        pytest.fail("no route start had dense traffic near the ego: the test cannot show the clearance")
    sim.reset("town_a", "clear_noon", "dense", 3, spec)
    assert _in_zone(sim, DEFAULT_CLEARANCE) == []
    assert sim._env.engine.traffic_manager.dropped_at_reset + len(sim.obstacles()) > 0


def test_the_episode_seed_places_the_pedestrians(sim):
    """MetaDrive's env reset reseeded every manager with the map's seed: every seed of a route had the same
    pedestrians (simulator revision 1). The same seed places them again, another seed elsewhere."""
    def pedestrians(seed: int) -> list:
        sim.reset("town_a", "clear_noon", "dense", seed=seed, render=False)
        people = sim._env.engine.managers["msfsu_pedestrians"].spawned_objects.values()
        return sorted(tuple(round(float(c), 3) for c in person.position) for person in people)

    first = pedestrians(1)
    assert first and pedestrians(2) != first and pedestrians(1) == first


@pytest.fixture(scope="module")
def dense(sim):
    """Ten seconds of dense traffic with the ego standing (brake), and the obstacles every 5 s."""
    sim.reset("town_a", "clear_noon", "dense", seed=11)
    seen = [sim.obstacles()]
    for step in range(100):
        sim.step(0.0, 0.0, 1.0)
        if step % 50 == 49:
            seen.append(sim.obstacles())
    return sim, seen


def test_traffic_drives_from_the_first_step_on_any_route(dense):
    """MetaDrive's trigger mode parked every car until the ego entered its block from the map's start."""
    _, seen = dense
    vehicles = [o for o in seen[-1] if o.kind != PEDESTRIAN]
    assert len(vehicles) >= 5
    assert sum(o.speed > 2.0 for o in vehicles) >= len(vehicles) // 2


def test_traffic_policy_sees_pedestrians_and_the_ego(dense):
    """MetaDrive's IDM read `obj.lane` of every object near it; its pedestrians had none, the policy fell
    back to seeing nothing at all and drove into the ego. Ours have a lane: the lookup must not fail."""
    sim, _ = dense
    engine = sim._env.engine
    people = [o for o in engine.get_objects(lambda o: isinstance(o, Person)).values()]
    assert people
    checked = 0
    for vehicle in engine.traffic_manager._traffic_vehicles:
        policy = engine.get_policy(vehicle.name)
        objects = vehicle.lidar.get_surrounding_objects(vehicle)
        if any(isinstance(o, Person) for o in objects) and policy.routing_target_lane is not None:
            FrontBackObjects.get_find_front_back_objs(objects, policy.routing_target_lane, vehicle.position,
                                                      policy.MAX_LONG_DIST)
            checked += 1
    assert checked > 0


def test_walkers_keep_to_the_kerb_line(dense):
    sim, _ = dense
    manager = sim._env.engine.managers["msfsu_pedestrians"]
    assert manager._walkers
    for walker in manager._walkers:
        _, lateral = walker.lane.local_coordinates(np.asarray(walker.agent.position))
        assert abs(lateral - walker.kerb_m) < 0.5  # on the sidewalk, curves included


def test_crossers_wait_for_the_ego(dense):
    """The ego stood still far from any junction: no crosser has stepped off the kerb."""
    sim, _ = dense
    crossers = sim._env.engine.managers["msfsu_pedestrians"]._crossers
    assert crossers and all(c.state == "waiting" for c in crossers)


def test_traffic_slows_for_turns_only(dense):
    """YieldingIDMPolicy takes turns at TURN_SPEED_KMH: which lanes are turns."""
    from msfsu_sim.traffic import _is_turn

    sim, _ = dense
    graph = sim._env.engine.current_map.road_network.graph
    lanes = [lane for roads in graph.values() for road in roads.values() for lane in road]
    turns = [lane for lane in lanes if _is_turn(lane)]
    assert turns and len(turns) < len(lanes) / 2
    for lane in turns:
        change = lane.heading_theta_at(lane.length) - lane.heading_theta_at(0.0)
        assert abs((change + np.pi) % (2 * np.pi) - np.pi) > np.radians(30)
