"""Simulator tests (one short episode on a training town; the first reset is the slow part)."""

import numpy as np
import pytest

from msfsu_common.road_option import RoadOption
from msfsu_sim import cameras
from msfsu_sim.cameras import linearize_depth
from msfsu_sim.environment import apply_fog, wet_road_texture
from msfsu_sim.route import is_junction_edge, wrap_angle
from msfsu_sim.scenarios import HELDOUT_TOWNS, TRAIN_TOWNS, WEATHERS
from msfsu_sim.semantics import colours_to_class_ids
from msfsu_common.semantic_classes import SemanticClass


def test_linearize_depth_maps_buffer_ends_to_near_and_far():
    metres = linearize_depth(np.array([0.0, 1.0], np.float32), 0.5, 200.0)
    assert metres.tolist() == pytest.approx([0.5, 200.0], rel=1e-4)


def test_fog_fades_far_pixels_to_fog_colour_and_keeps_near_ones():
    weather = WEATHERS["foggy_day"]
    rgb = np.zeros((1, 2, 3), np.uint8)
    depth = np.array([[0.0, 1000.0]], np.float32)
    out = apply_fog(rgb, depth, weather)
    assert out[0, 0].tolist() == [0, 0, 0]
    assert out[0, 1].tolist() == list(weather.fog_rgb)


def test_wet_asphalt_is_darker_and_bluer_and_dry_weather_keeps_it():
    dry = np.full((4, 3), 100, np.uint8)  # B, G, R texels
    wet = wet_road_texture(dry, WEATHERS["soft_rain_dusk"].wetness).astype(int)
    assert (wet < 100).all() and wet[0, 0] > wet[0, 2]  # blue channel darkened least
    assert np.array_equal(wet_road_texture(dry, 0.0), dry)


def test_train_and_heldout_towns_differ_in_layout():
    assert {t.blocks for t in TRAIN_TOWNS.values()}.isdisjoint({t.blocks for t in HELDOUT_TOWNS.values()})


@pytest.fixture(scope="module")
def episode(sim):
    first = sim.reset("town_a", "clear_noon", "regular", seed=5)
    frames = [first] + [sim.step(0.0, 0.4, 0.0) for _ in range(20)]
    return sim, frames


def test_images_are_pixel_aligned_with_expected_shapes_and_types(episode):
    _, frames = episode
    obs = frames[-1]
    assert obs.rgb.shape == (300, 400, 3) and obs.rgb.dtype == np.uint8
    assert obs.depth.shape == (300, 400) and obs.depth.dtype == np.float32
    assert obs.semantic_ids.shape == (300, 400) and obs.semantic_ids.dtype == np.uint8
    assert obs.semantic_ids.max() <= SemanticClass.OTHER
    lower = obs.semantic_ids[200:]
    assert (lower == SemanticClass.ROAD).mean() > 0.5  # the car starts on a straight road
    assert (lower == SemanticClass.ROAD_LINE).any()
    assert (obs.semantic_ids[:50] == SemanticClass.OTHER).all()  # sky
    assert obs.rgb[250:].std() > 3  # textured road, not a blank buffer


def test_depth_from_the_rgb_pass_equals_a_dedicated_depth_render(episode):
    """RGB and depth come from one scene pass; a separate depth camera with the same mount and lens (the
    way MetaDrive renders depth) must read the same metres at every pixel."""
    sim, _ = episode
    engine = sim._env.engine
    engine.add_image_sensor("reference_depth", cameras.MetricDepthCamera, (sim.config.width, sim.config.height))
    try:
        reference = engine.get_sensor("reference_depth")
        mount = sim.config.mount
        reference.track(sim._env.agent.origin, (mount.x, mount.y, mount.z), (0.0, mount.pitch_deg, 0.0))
        reference.get_lens().setFov(mount.fov_deg)
        reference.get_lens().setNearFar(mount.near_m, mount.far_m)
        engine.graphicsEngine.renderFrame()
        from_rgb_pass, dedicated = cameras.read_depth(engine), reference.get_rgb_array_cpu()
    finally:
        engine.sensors.pop("reference_depth").destroy()
    assert from_rgb_pass.shape == dedicated.shape == (sim.config.height, sim.config.width)
    assert np.allclose(from_rgb_pass, dedicated, rtol=1e-4, atol=1e-3)
    assert from_rgb_pass.min() < 10.0 and (from_rgb_pass >= sim.config.mount.far_m * 0.999).any()  # road and sky


def test_the_hidden_ego_car_is_not_in_the_cameras_view(episode):
    """The ego car is hidden from the cameras (it would be drawn every frame); showing it changes nothing."""
    sim, _ = episode
    engine, ego = sim._env.engine, sim._env.agent
    engine.graphicsEngine.renderFrame()
    hidden = cameras.read_depth(engine)
    ego.origin.show()
    try:
        engine.graphicsEngine.renderFrame()
        shown = cameras.read_depth(engine)
    finally:
        cameras.mount_cameras(engine, ego, sim.config.mount)
    assert (np.abs(hidden - shown) > 0.1).mean() < 1e-3  # only animated pedestrians move between the frames


def test_the_lean_terrain_shader_draws_the_same_image_as_metadrives(episode):
    """The project's terrain shader leaves out texture reads whose result never shows (without the shadow
    pass); the frame must be identical to MetaDrive's shader's, pixel for pixel."""
    from panda3d.core import ClockObject

    from msfsu_sim.environment import STEP_S

    sim, frames = episode
    engine = sim._env.engine
    assert sim.config.quality.lean_terrain_shader and not sim.config.quality.shadows
    clock = ClockObject.get_global_clock()
    clock.set_dt(1e-9)  # the same pedestrian pose in both frames (the walk animation follows the clock)
    images = {}
    try:
        for name, fragment in (("metadrive", None), ("lean", cameras.LEAN_TERRAIN_SHADER)):
            cameras.set_terrain_shader(engine, fragment)
            engine.graphicsEngine.renderFrame()
            images[name] = cameras.read_rgb(engine)
    finally:
        clock.set_dt(STEP_S)
        cameras.set_terrain_shader(engine, cameras.LEAN_TERRAIN_SHADER)
    assert (frames[-1].semantic_ids == SemanticClass.ROAD_LINE).any()  # the lane-line branch is drawn
    assert np.array_equal(images["metadrive"], images["lean"])


def test_the_sidewalk_is_drawn_without_anisotropic_filtering_and_only_its_far_pixels_change(episode):
    """MetaDrive's 8x anisotropic sidewalk texture is set to 1x after every reset (Quality.anisotropic_sidewalks,
    simulator revision 4): what that changes must be sidewalk pixels only, and little."""
    from panda3d.core import ClockObject, TextureAttrib

    from msfsu_sim import metadrive_compat
    from msfsu_sim.environment import STEP_S

    sim, frames = episode
    engine = sim._env.engine
    assert not sim.config.quality.anisotropic_sidewalks
    sidewalk_textures = set()
    for geom_node in engine.worldNP.findAllMatches("**/+GeomNode"):
        if "sidewalk" in str(geom_node):
            attrib = geom_node.getNetState().getAttrib(TextureAttrib)
            sidewalk_textures |= {attrib.getOnTexture(attrib.getOnStage(i)) for i in range(attrib.getNumOnStages())}
    assert [texture.getAnisotropicDegree() for texture in sidewalk_textures if texture.getName() == "color"] == [1]
    clock = ClockObject.get_global_clock()
    clock.set_dt(1e-9)  # the same pedestrian pose in both frames
    images = {}
    try:
        for degree in (8, 1):
            metadrive_compat.sidewalk_filtering(engine, anisotropic_degree=degree)
            engine.graphicsEngine.renderFrame()
            images[degree] = cameras.read_rgb(engine).astype(np.int16)
    finally:
        clock.set_dt(STEP_S)
        metadrive_compat.sidewalk_filtering(engine, anisotropic_degree=1)
    changed = np.abs(images[8] - images[1]).max(axis=-1) > 0
    sidewalk = frames[-1].semantic_ids == SemanticClass.SIDEWALK
    assert sidewalk.any() and changed.any()  # the sidewalk is in view and the filter shows on it
    assert not (changed & ~sidewalk).any()
    assert np.abs(images[8] - images[1]).mean() < 0.5


def test_metric_depth_grows_towards_the_horizon_on_a_straight_road(episode):
    _, frames = episode
    obs = frames[0]
    column = obs.depth[:, 200]
    road_rows = np.nonzero(obs.semantic_ids[:, 200] <= SemanticClass.ROAD_LINE)[0]
    road_depth = column[road_rows]  # top to bottom
    assert np.all(np.diff(road_depth) < 0)  # nearer (lower) rows are closer
    assert 1.5 < road_depth[-1] < 10.0  # ground just in front of the bonnet
    assert road_depth[0] > 40.0


def test_time_odometry_and_progress_advance(episode):
    _, frames = episode
    assert [f.time_s for f in frames[:3]] == pytest.approx([0.0, 0.1, 0.2])
    assert frames[-1].odometry.speed > 1.0
    assert frames[-1].route_progress_m > frames[0].route_progress_m
    assert not any(f.collision or f.out_of_road for f in frames)


def test_route_options_through_the_known_intersection(episode):
    sim, _ = episode
    route = sim.route
    checkpoints = sim._env.agent.navigation.checkpoints
    junctions = [(a, b) for a, b in zip(checkpoints[:-1], checkpoints[1:]) if is_junction_edge(a, b)]
    assert [b[1] for _, b in junctions] == ["X", "T"]  # town_a = S X C T S
    labels = route.options
    turn = labels != RoadOption.LANE_FOLLOW
    starts = np.nonzero(turn & ~np.r_[False, turn[:-1]])[0]
    ends = np.nonzero(turn & ~np.r_[turn[1:], False])[0]
    assert len(starts) == len(junctions)  # one labelled stretch per junction crossing
    # Each stretch's label agrees with the heading change across it; curves (C) stay LANE_FOLLOW.
    for start, end in zip(starts, ends):
        option = RoadOption(int(labels[start]))
        assert (labels[start:end + 1] == option).all()
        change = wrap_angle(route.poses[end, 2] - route.poses[start, 2])
        assert (option is RoadOption.LEFT) == (change > 0.5) and (option is RoadOption.RIGHT) == (change < -0.5)
    follow_heading_change = np.abs(np.diff(np.unwrap(route.poses[~turn, 2]))).sum()
    assert follow_heading_change > 0.5  # curves exist but are not labelled as turns


def test_a_blind_episode_renders_nothing_and_the_next_one_sees_again(sim):
    """reset(render=False): the expert's benchmark episodes need no camera (rendering was ~9/10 of a step)."""
    blind = sim.reset("town_a", "clear_noon", "empty", seed=5, render=False)
    blind = sim.step(0.0, 0.4, 0.0)
    assert blind.rgb is None and blind.depth is None and blind.semantic_ids is None
    engine = sim._env.engine.graphicsEngine
    outputs = [engine.getWindow(i) for i in range(engine.getNumWindows())]
    assert not any(output.isActive() for output in outputs)  # no pass renders at all
    seeing = sim.reset("town_a", "clear_noon", "empty", seed=5)
    assert seeing.rgb.shape == (300, 400, 3) and seeing.semantic_ids is not None
    assert seeing.odometry == sim.reset("town_a", "clear_noon", "empty", seed=5, render=False).odometry


def test_traffic_in_the_class_id_mask_is_where_depth_sees_it(sim):
    """Traffic is drawn with light meshes (levels of detail chosen per camera by distance): the semantic
    pass must pick the same level as the RGB/depth pass. The pixels whose depth changes when traffic and
    pedestrians are hidden are the pixels the class-id mask calls vehicle-or-pedestrian."""
    from metadrive.component.traffic_participants.base_traffic_participant import BaseTrafficParticipant
    from metadrive.component.vehicle.base_vehicle import BaseVehicle

    from msfsu_sim.expert import Expert

    obs = sim.reset("town_a", "clear_noon", "dense", seed=11)
    expert = Expert()
    for _ in range(60):  # drive until traffic fills a good part of the image
        action, longitudinal = expert.drive(obs, sim)
        obs = sim.step(action.steer, longitudinal.throttle, longitudinal.brake)
        if (obs.semantic_ids == SemanticClass.VEHICLE_OR_PEDESTRIAN).sum() > 1000:
            break
    engine, ego = sim._env.engine, sim._env.agent
    engine.graphicsEngine.renderFrame()
    shown = cameras.read_depth(engine)
    ids = colours_to_class_ids(cameras.read_semantic_colours(engine))
    others = [obj for obj in engine.get_objects().values()
              if isinstance(obj, (BaseVehicle, BaseTrafficParticipant)) and obj is not ego]
    for obj in others:
        obj.origin.hide()
    try:
        engine.graphicsEngine.renderFrame()
        hidden = cameras.read_depth(engine)
    finally:
        for obj in others:
            obj.origin.show()
        cameras.mount_cameras(engine, ego, sim.config.mount)
    from_depth = np.abs(shown - hidden) > 0.05
    from_ids = ids == SemanticClass.VEHICLE_OR_PEDESTRIAN
    assert from_ids.sum() > 1000  # traffic in view
    iou = (from_depth & from_ids).sum() / (from_depth | from_ids).sum()
    assert iou > 0.98, f"IoU {iou:.3f} of {from_ids.sum()} class-id pixels and {from_depth.sum()} depth pixels"


def _expert_drive(sim, seed: int, steps: int, render: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """(per step: ego pose and speed, traffic count and summed positions; the last RGB frame or None)."""
    from metadrive.component.vehicle.base_vehicle import BaseVehicle

    from msfsu_sim.expert import Expert

    obs = sim.reset("town_a", "clear_noon", "dense", seed=seed, render=render)
    expert, rows = Expert(), []
    for _ in range(steps):
        action, longitudinal = expert.drive(obs, sim)
        obs = sim.step(action.steer, longitudinal.throttle, longitudinal.brake)
        traffic = np.array([v.position for v in sim._env.engine.get_objects().values()
                            if isinstance(v, BaseVehicle) and v is not sim._env.agent]).reshape(-1, 2)
        odometry = obs.odometry
        rows.append([odometry.x, odometry.y, odometry.yaw, odometry.speed, len(traffic), *traffic.sum(0)])
    return np.asarray(rows), obs.rgb


def test_an_episode_is_identical_whatever_ran_before_it_rendered_or_blind(sim):
    """Paired comparisons need the same traffic on the same route and seed in every run. MetaDrive reused
    vehicles of earlier episodes (their Bullet state differed in the last bits: dense traffic diverged
    after a few steps) and animated pedestrians on the wall clock (their pose in the images differed)."""
    first, first_rgb = _expert_drive(sim, seed=11, steps=60, render=True)
    _expert_drive(sim, seed=12, steps=30, render=False)  # something else ran in between
    again, again_rgb = _expert_drive(sim, seed=11, steps=60, render=True)
    blind, blind_rgb = _expert_drive(sim, seed=11, steps=60, render=False)
    assert first[:, 4].min() >= 5  # dense traffic in the episode
    assert np.array_equal(first, again) and np.array_equal(first, blind)
    assert np.array_equal(first_rgb, again_rgb) and blind_rgb is None


def test_every_episode_starts_in_new_bullet_worlds(sim):
    """Bullet's broadphase keeps state from episode to episode (its AABB tree and pair cache); the same dense
    route drove 1169 steps in a fresh process and 816 after another route (the slow reproduction:
    msfsu_evaluation/test/test_closed_loop_routes.py). Each reset swaps in new worlds once MetaDrive has
    emptied the old ones; the lidar's broad-phase detector is made anew, nothing moves over."""
    from msfsu_sim.physics_world import attached

    engine_worlds = lambda: (sim._env.engine.physics_world.dynamic_world, sim._env.engine.physics_world.static_world)
    sim.reset("town_a", "clear_noon", "regular", seed=5, render=False)
    before = engine_worlds()
    counts = [len(attached(world)) for world in before]
    sim.step(0.0, 0.5, 0.0)
    sim.reset("town_a", "clear_noon", "regular", seed=5, render=False)
    after = engine_worlds()
    assert after[0] is not before[0] and after[1] is not before[1]
    assert [len(attached(world)) for world in after] == counts  # the same episode attached the same bodies
    assert sim._env.engine.physics_world_moved_at_reset == 0


def test_the_kerb_and_solid_lines_are_reported_as_the_car_meets_them(sim):
    """Routes v3 rules read these: a car steering left on a two-way road touches the solid centre line; one
    steering right strikes the kerb (static_collision "sidewalk"), which MetaDrive does not end on."""
    def drive(steer: float) -> list:
        observations = [sim.reset("town_a", "clear_noon", "empty", seed=3, render=False)]
        for _ in range(60):
            observations.append(sim.step(steer, 0.5, 0.0))
            if observations[-1].done or observations[-1].static_collision:
                break
        return observations

    left = drive(-0.3)
    assert any(obs.solid_line for obs in left) and not left[0].solid_line
    right = drive(0.3)
    assert right[-1].static_collision == "sidewalk" and not any(obs.static_collision for obs in right[:-1])


def test_a_stop_signal_inside_panda3ds_task_loop_ends_the_step_then_interrupts(sim, capfd):
    """msfsu-benchmark's workers turn SIGTERM into KeyboardInterrupt (interrupt_on_signals). One arriving while
    Panda3D runs a Python task (its frame render is one) was raised inside the task, and Panda3D's task manager
    printed it as a traceback on every stopped run; now the step ends whole and the interrupt comes after it."""
    import os
    import signal

    from msfsu_common.processes import signals_interrupt

    sim.reset("town_a", "clear_noon", "empty", seed=5)
    task_manager = sim._env.engine.taskMgr

    def stop_signal(task):
        os.kill(os.getpid(), signal.SIGTERM)
        return task.done

    try:
        with signals_interrupt():
            steps = sim._step
            capfd.readouterr()
            task_manager.add(stop_signal, "msfsu_test_stop_signal")
            with pytest.raises(KeyboardInterrupt):
                sim.step(0.0, 0.4, 0.0)
            assert "Traceback" not in capfd.readouterr().err
            assert sim._step == steps + 1  # the step was not cut short
    finally:
        task_manager.remove("msfsu_test_stop_signal")
    assert sim.step(0.0, 0.4, 0.0).rgb is not None  # and the simulator goes on


CLASS_PATCHES = ["prc: no multisampling, no audio", "prc: render states freed at once (no periodic collection)",
                 "FilterManager.render_scene_into: single-sampled",
                 "ImageBuffer._create_buffer: single-sampled", "Terrain._load_mesh_terrain_textures: anisotropic degree",
                 "AssetLoader.file_path: light meshes"]
ENGINE_PATCHES = ["engine.task_manager: timed", "engine._object_clean_check: new Bullet worlds",
                  "engine: main window pass off", "engine.reset: no warm-up frames",
                  "engine.terrain.reset: rebuilt only for a new map",
                  "engine.terrain._generate_mesh_vis_terrain: triangle width"]


def test_metadrive_is_patched_from_one_module_classes_once_and_each_engine_in_order(episode):
    """Every patch of MetaDrive goes through metadrive_compat: the class patches once, before the first engine,
    then the engine patches on every engine made (one per town change), in the same order."""
    from msfsu_sim import metadrive_compat

    applied = metadrive_compat.applied()
    engines = (len(applied) - len(CLASS_PATCHES)) // len(ENGINE_PATCHES)
    assert engines >= 1 and applied == CLASS_PATCHES + ENGINE_PATCHES * engines
