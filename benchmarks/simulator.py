"""Speed of the embedded simulator per mode, with a per-stage breakdown, side by side in one run.

    python benchmarks/simulator.py                          # all modes, writes benchmarks/simulator_results.{md,json}
    python benchmarks/simulator.py --modes evaluation --steps 100 --out /tmp/sim.md
    python benchmarks/simulator.py --frames docs/images/sim  # also example RGB / depth / class-id PNGs per mode

Modes (each in a fresh process: one MetaDrive engine per process):
- `stock`: MetaDrive's own passes, what this package did before: the hidden main window's scene pass, a
  separate depth render, RGB and semantic passes.
- `collection`: what `msfsu-collect` records: RGB and metric depth from one scene pass + the semantic pass.
- `evaluation`: what driving needs (closed-loop benchmark, `sim` profile): RGB and metric depth only.
- `evaluation_full_meshes`: `evaluation` with MetaDrive's full traffic and pedestrian models instead of the
  light meshes (`msfsu_sim.light_meshes`): what the light meshes save, on the same scene.
- `evaluation_metadrive_terrain`: `evaluation` with MetaDrive's terrain shader instead of the lean copy
  (`msfsu_sim/shaders/terrain_rgb.frag.glsl`, the same image): what the lean shader saves.
- `evaluation_anisotropic_sidewalks`: `evaluation` with MetaDrive's 8x anisotropic filter on the sidewalk texture
  (simulator revision 3 and before): what drawing it without saves.

Every mode but `stock` and `evaluation_full_meshes` draws traffic with the light meshes; every mode but `stock`
and `evaluation_metadrive_terrain` draws the terrain with the lean shader; only `stock` and
`evaluation_anisotropic_sidewalks` filter the sidewalk anisotropically.

Per mode: resets (new engine, same town, another town), steps/s with the expert driving in traffic, ms per
step of each stage (render, physics + traffic, read-backs, fog, expert, ROS message build and publish),
and what each render pass costs on its own (`renderFrame` with only that buffer active, minus the frame
with none). The 1-minute load average is printed with every mode: numbers taken under load are not
comparable.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from msfsu_common.benchmark_run import BenchmarkRun, load_1min
from msfsu_evaluation.records.simulator import SimulatorMode, SimulatorResults, SimulatorSetup

MODES = ("stock", "collection", "evaluation", "evaluation_full_meshes", "evaluation_metadrive_terrain",
         "evaluation_anisotropic_sidewalks")
DEFAULT_OUT = Path(__file__).with_name("simulator_results.md")
PASS_REPEATS = 20


def _config(mode: str, width: int, height: int):
    from msfsu_sim.environment import Quality, SimConfig

    stock = mode == "stock"
    return SimConfig(width=width, height=height, labels=mode in ("stock", "collection"),
                     quality=Quality(main_pass=stock, depth_pass=stock,
                                     light_meshes=mode not in ("stock", "evaluation_full_meshes"),
                                     lean_terrain_shader=mode not in ("stock", "evaluation_metadrive_terrain"),
                                     anisotropic_sidewalks=mode in ("stock", "evaluation_anisotropic_sidewalks")))


def _render_passes(engine) -> dict[str, float]:
    """ms of `renderFrame` with only one active buffer, minus the frame with none."""
    graphics = engine.graphicsEngine
    buffers = [graphics.getWindow(i) for i in range(graphics.getNumWindows())]
    active = [buffer for buffer in buffers if buffer.isActive()]

    def frame_ms() -> float:
        start = time.perf_counter()
        for _ in range(PASS_REPEATS):
            graphics.renderFrame()
        return (time.perf_counter() - start) / PASS_REPEATS * 1000

    labels: list[tuple[object, str]] = []  # (buffer, what it draws)
    for name, sensor in engine.sensors.items():
        if getattr(sensor, "buffer", None) is None:
            continue  # lidar and other non-image sensors
        scene_buffers = getattr(getattr(sensor, "manager", None), "buffers", [])
        labels += [(buffer, f"{name} scene pass") for buffer in scene_buffers]
        labels.append((sensor.buffer, f"{name} tone map" if scene_buffers else f"{name} scene pass"))
    if engine.pbrpipe is not None:
        labels += [(buffer, "main window scene pass") for buffer in engine.pbrpipe.manager.buffers]

    def label_of(buffer) -> str:
        return next((label for known, label in labels if known == buffer), buffer.getName())

    try:
        for buffer in active:
            buffer.setActive(False)
        empty = frame_ms()
        passes = {}
        for index, buffer in enumerate(active):
            buffer.setActive(True)
            passes[f"{label_of(buffer)} ({buffer.getXSize()}x{buffer.getYSize()})"] = round(frame_ms() - empty, 2)
            buffer.setActive(False)
        passes["frame with no buffer"] = round(empty, 2)
    finally:
        for buffer in active:
            buffer.setActive(True)
    return passes


def run_mode(mode: str, steps: int, warmup: int, width: int, height: int, town: str, other_town: str,
             traffic: str, frames: str | None) -> dict:
    """One mode in this (fresh) process; returns its figures."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from domain_coordinator import domain_id

    from msfsu_common.ros_env import configure_ros_environment

    configure_ros_environment()
    import rclpy
    from rclpy.node import Node

    from msfsu_sim.environment import SimEnvironment
    from msfsu_sim.expert import Expert
    from msfsu_sim.lockstep import LockstepLink

    result: dict = {"mode": mode, "load_1min": load_1min()}
    env = SimEnvironment(_config(mode, width, height))
    clock = env.clock
    resets = {}
    start = time.perf_counter()
    obs = env.reset(town, "clear_noon", traffic, seed=0)
    resets["new engine"] = time.perf_counter() - start
    same = []
    for seed in (1, 2):
        start = time.perf_counter()
        obs = env.reset(town, "clear_noon", traffic, seed=seed)
        same.append(time.perf_counter() - start)
    resets["same town"] = float(np.mean(same))

    with domain_id() as domain:
        rclpy.init(domain_id=domain)
        node = Node("simulator_benchmark")
        link = LockstepLink(node, env)  # the sim_bridge's publishers and message building
        expert = Expert()
        for _ in range(warmup):
            obs = env.step(*_drive(expert, obs, env))
        clock.clear()
        start = time.perf_counter()
        for _ in range(steps):
            with clock.stage("expert"):
                control = _drive(expert, obs, env)
            obs = env.step(*control)
            with clock.stage("messages + publish"):
                link.publish_frame(obs)
        elapsed = time.perf_counter() - start
        node.destroy_node()
        rclpy.shutdown()
    stages = clock.ms_per(steps)
    stages.pop("expert", None)
    publish_ms = stages.pop("messages + publish")
    expert_ms = 1000 * clock.seconds["expert"] / steps
    result["steps_per_s"] = round(steps / (elapsed - clock.seconds["messages + publish"]), 2)
    result["steps_per_s_with_publish"] = round(steps / elapsed, 2)
    result["stages_ms"] = {**{name: round(value, 2) for name, value in stages.items()
                              if not name.startswith("reset")},
                           "expert": round(expert_ms, 2), "messages + publish (sim_bridge)": round(publish_ms, 2)}
    result["render_passes_ms"] = _render_passes(env._env.engine)
    if frames:
        from msfsu_sim.frames import save_frames

        result["frames"] = [str(path) for path in save_frames(obs, Path(frames), f"{town}_{mode}")]
    start = time.perf_counter()
    env.reset(other_town, "clear_noon", traffic, seed=0)
    resets["other town"] = time.perf_counter() - start
    result["reset_s"] = {name: round(value, 2) for name, value in resets.items()}
    env.close()
    return result


def _drive(expert, obs, env) -> tuple[float, float, float]:
    action, longitudinal = expert.drive(obs, env)
    return action.steer, longitudinal.throttle, longitudinal.brake


def setup(args: argparse.Namespace, run: BenchmarkRun) -> SimulatorSetup:
    """What the page says of `run` (ended) and its options."""
    return SimulatorSetup(date_end=run.date_end, command=run.command, machine=run.machine, town=args.town,
                          traffic=args.traffic, width=args.width, height=args.height, steps=args.steps,
                          warmup=args.warmup)


# (file name, left mode, right mode, labels): two modes of the same scene side by side, with what differs
COMPARISONS = (
    ("light_vs_full_meshes", "evaluation_full_meshes", "evaluation", ("MetaDrive's models", "light meshes")),
    ("anisotropic_vs_plain_sidewalks", "evaluation_anisotropic_sidewalks", "evaluation",
     ("sidewalk 8x anisotropic", "sidewalk 1x (revision 4)")),
)


def side_by_side(frames: Path, town: str, name: str, left: str, right: str, labels: tuple[str, str]) -> Path | None:
    """`<town>_<name>.png`: the RGB and depth frames of two modes of the same scene side by side, and a third
    column with their absolute difference x8 (black where they are equal)."""
    import cv2

    rows = []
    for kind in ("rgb", "depth"):
        pair = [cv2.imread(str(frames / f"{town}_{mode}_{kind}.png")) for mode in (left, right)]
        if any(image is None for image in pair) or pair[0].shape != pair[1].shape:
            return None
        difference = np.clip(np.abs(pair[0].astype(np.int16) - pair[1].astype(np.int16)) * 8, 0, 255)
        rows.append(np.hstack([*pair, difference.astype(np.uint8)]))
    image = np.vstack(rows)
    width = rows[0].shape[1] // 3
    for x, label in ((6, labels[0]), (width + 6, labels[1]), (2 * width + 6, "difference x8")):
        cv2.putText(image, label, (x, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 2, cv2.LINE_AA)
        cv2.putText(image, label, (x, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    path = frames / f"{town}_{name}.png"
    cv2.imwrite(str(path), image)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--width", type=int, default=400)
    parser.add_argument("--height", type=int, default=300)
    parser.add_argument("--town", default="town_a")
    parser.add_argument("--other-town", default="town_h1", help="town of the town-change reset")
    parser.add_argument("--traffic", default="regular")
    parser.add_argument("--frames", help="write example PNGs of the last frame of each mode here")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown table; JSON beside it")
    args = parser.parse_args(argv)

    run = BenchmarkRun.start("python benchmarks/simulator.py")  # the page's command line: sys.argv
    results = SimulatorResults([])
    context = multiprocessing.get_context("spawn")
    for mode in args.modes:
        with ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
            result = pool.submit(run_mode, mode, args.steps, args.warmup, args.width, args.height, args.town,
                                 args.other_town, args.traffic, args.frames).result()
        print(json.dumps(result), flush=True)
        results.rows.append(SimulatorMode.from_dict(result))
    if args.frames:
        for name, left, right, labels in COMPARISONS:
            side_by_side(Path(args.frames), args.town, name, left, right, labels)
    text = results.page(setup(args, run.end()))
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    args.out.with_suffix(".json").write_text(results.to_json())
    return 0


if __name__ == "__main__":
    sys.exit(main())
