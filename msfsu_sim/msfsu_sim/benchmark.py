"""Steps/s of the simulator with the three front cameras, per quality setting, and example frames.

    python -m msfsu_sim.benchmark --steps 40                 # this package's defaults
    python -m msfsu_sim.benchmark --shadows --triangle-px 10  # MetaDrive's stock render settings
    python -m msfsu_sim.benchmark --frames docs/images/sim    # also write RGB/depth/semantic PNGs
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from msfsu_sim.environment import Observation, Quality, SimConfig, SimEnvironment
from msfsu_sim.semantics import colourise


def depth_colours(depth: np.ndarray, max_m: float = 80.0) -> np.ndarray:
    """(H, W) metres -> (H, W, 3) RGB, log scale so near structure stays visible."""
    scaled = np.log1p(np.clip(depth, 0, max_m)) / np.log1p(max_m)
    return cv2.applyColorMap((255 * (1 - scaled)).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1]


def save_frames(obs: Observation, directory: Path, prefix: str) -> list[Path]:
    directory.mkdir(parents=True, exist_ok=True)
    images = {"rgb": obs.rgb, "depth": depth_colours(obs.depth), "semantic": colourise(obs.semantic_ids)}
    paths = []
    for name, rgb in images.items():
        path = directory / f"{prefix}_{name}.png"
        cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 9])
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--town", default="town_a")
    parser.add_argument("--weather", default="clear_noon")
    parser.add_argument("--traffic", default="regular")
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--width", type=int, default=400)
    parser.add_argument("--height", type=int, default=300)
    parser.add_argument("--shadows", action="store_true")
    parser.add_argument("--no-terrain", action="store_true")
    parser.add_argument("--triangle-px", type=int, default=Quality().terrain_triangle_px)
    parser.add_argument("--frames", type=Path, help="write example PNGs of the last frame here")
    args = parser.parse_args(argv)

    from msfsu_sim.expert import Expert

    quality = Quality(shadows=args.shadows, terrain=not args.no_terrain, terrain_triangle_px=args.triangle_px)
    env = SimEnvironment(SimConfig(width=args.width, height=args.height, quality=quality))
    start = time.perf_counter()
    obs = env.reset(args.town, args.weather, args.traffic, seed=0)
    reset_s = time.perf_counter() - start
    expert = Expert()
    start = time.perf_counter()
    for _ in range(args.steps):
        action, control = expert.drive(obs, env)
        obs = env.step(action.steer, control.throttle, control.brake)
    rate = args.steps / (time.perf_counter() - start)
    print(f"{quality} {args.width}x{args.height}: first reset {reset_s:.1f} s, {rate:.2f} steps/s")
    if args.frames:
        for path in save_frames(obs, args.frames, f"{args.town}_{args.weather}"):
            print(path)
    env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
