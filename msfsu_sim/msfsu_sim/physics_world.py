"""A new Bullet world for every episode, so an episode does not depend on what the process simulated before it.

MetaDrive keeps one pair of Bullet worlds (dynamic and static) for the life of the engine. Every reset empties
them (objects, map and terrain are detached) but Bullet's broadphase keeps state between episodes: its dynamic
AABB tree is re-balanced a little on every step and its pair cache and stage counters carry on, so the order in
which contacts are found and solved in an episode depended on how many steps and which bodies came before. In
dense traffic that last-bit difference grows into different trajectories: the same route and seed drove differently
in a fresh process and after another route of the same town (the test that holds it:
msfsu_evaluation/test/test_closed_loop_routes.py).

`renew(engine)`, hooked into MetaDrive's reset by `metadrive_compat.renew_worlds_each_reset`, swaps in new
worlds at the moment they are empty (after every manager's `before_reset` and the terrain's, before anything of
the next episode is attached), configured as MetaDrive configures its own (collision groups, gravity, the contact
callback). Bodies still attached then are those MetaDrive never detaches: the lidar's broad-phase detectors are
dropped (`forget_lidar_detectors`), anything else moves to the new world in the old one's order (nothing in this
configuration).
"""

from __future__ import annotations

from typing import Any

_KINDS = ("RigidBodies", "Ghosts", "Vehicles", "Characters", "SoftBodies")


def attached(world: Any) -> list:
    """Every node attached to a Panda3D BulletWorld (constraints aside), in the world's order."""
    return [node for kind in _KINDS for node in getattr(world, f"get{kind}")()]


def forget_lidar_detectors(engine: Any) -> None:
    """Drop the lidar's broad-phase detector ghosts (MetaDrive makes one per radius on first use and keeps it in the
    static world for the engine's life, moved to wherever it last perceived). Kept, it entered each new world where
    the last episode left it and ahead of the map, so the static world's broadphase differed from a fresh process's
    and ray and contact queries (lane lookups) with it: nocrash_dense heldout/12 drove 1376 steps alone and 1105
    after heldout/00. Dropped, the first query of the episode makes it again, as in a fresh process."""
    lidar = getattr(engine, "sensors", {}).get("lidar")
    if lidar is None:
        return
    for detector in lidar.broad_detectors.values():
        engine.physics_world.static_world.remove(detector.node())
        if detector in lidar._node_path_list:
            lidar._node_path_list.remove(detector)
        detector.removeNode()
    lidar.broad_detectors.clear()


def renew(engine: Any) -> int:
    """Replace the engine's dynamic and static worlds with new ones; returns how many nodes were moved over."""
    from metadrive.engine.core.collision_callback import collision_callback
    from metadrive.engine.core.physics_world import PhysicsWorld
    from panda3d.core import PythonCallbackObject

    forget_lidar_detectors(engine)
    old = engine.physics_world
    if old.dynamic_world.getNumConstraints() or old.static_world.getNumConstraints():
        raise RuntimeError("physics_world.renew: constraints are still attached; the world cannot be replaced")
    debug = old.static_world is old.dynamic_world
    new = PhysicsWorld(debug, disable_collision=engine.global_config["disable_collision"])
    new.dynamic_world.setContactAddedCallback(PythonCallbackObject(collision_callback))
    moved = 0
    for source, target in ((old.dynamic_world, new.dynamic_world), (old.static_world, new.static_world)):
        if debug and source is old.static_world:
            break
        for node in attached(source):
            source.remove(node)
            target.attach(node)
            moved += 1
    old.dynamic_world.clearContactAddedCallback()
    old.destroy()
    # Replace the worlds inside MetaDrive's PhysicsWorld object: objects reach them through engine.physics_world.
    old.dynamic_world, old.static_world = new.dynamic_world, new.static_world
    return moved
