"""Pictures of each h1hand task's start state, rendered offscreen:

    MUJOCO_GL=egl python -m humanoid_envs.render docs/

writes `docs/h1hand_tasks.png`, one strip of the five tasks after `reset(seed=0)`, labelled.
The cameras here are free cameras chosen for a portrait of the robot, both hands and the
task's objects; the tasks' own `<task>_view` cameras (what `env.render()` shows) stay as
they are. Needs Pillow (`pip install .[render]`) for the labels and the palette PNG.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import gymnasium as gym
import mujoco
import numpy as np

import humanoid_envs  # noqa: F401  (registers the tasks)

if TYPE_CHECKING:
    from PIL.Image import Image


@dataclass(frozen=True)
class View:
    """A MuJoCo free camera: it orbits `lookat` at `distance` (m), angles in degrees."""

    lookat: tuple[float, float, float]
    distance: float
    azimuth: float
    elevation: float


# The robot faces +x. Azimuth 150 looks at its front-right; bookshelf's shelf stands in front
# of it, so that view comes from behind-left, over the shoulder into the shelf.
VIEWS = {
    "h1hand-stand-v0": View((0.0, 0.0, 0.9), 3.0, 150.0, -12.0),
    "h1hand-powerlift-v0": View((0.25, 0.0, 0.8), 3.4, 150.0, -15.0),
    "h1hand-cube-v0": View((0.2, 0.0, 1.0), 2.5, 165.0, -18.0),
    "h1hand-bookshelf_simple-v0": View((0.5, 0.0, 1.0), 3.4, 58.0, -22.0),
    "h1hand-bookshelf_hard-v0": View((0.5, 0.0, 1.0), 3.4, 58.0, -22.0),
}


def render_start_state(env_id: str, view: View, width: int, height: int) -> np.ndarray:
    """RGB frame of `env_id` right after `reset(seed=0)`, seen from `view`."""
    env = gym.make(env_id)
    env.reset(seed=0)
    scene = env.unwrapped
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = view.lookat
    camera.distance, camera.azimuth, camera.elevation = view.distance, view.azimuth, view.elevation
    renderer = mujoco.Renderer(scene.model, height, width)
    try:
        renderer.update_scene(scene.data, camera=camera)
        return renderer.render().copy()
    finally:
        renderer.close()
        env.close()


def labelled(frame: np.ndarray, label: str) -> Image:
    """The frame as a Pillow image with `label` on a dark band at its top."""
    from PIL import Image as PILImage
    from PIL import ImageDraw, ImageFont

    image = PILImage.fromarray(frame)
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default(size=max(12, frame.shape[0] // 22))
    left, top, right, bottom = draw.textbbox((0, 0), label, font=font)
    pad = 4
    draw.rectangle((0, 0, image.width, bottom - top + 3 * pad), fill=(20, 24, 32))
    draw.text(((image.width - right + left) // 2, pad - top), label, fill="white", font=font)
    return image


def task_strip(width: int = 300, height: int = 380) -> Image:
    """One Pillow image: every task's start state side by side, each labelled with its id."""
    from PIL import Image as PILImage

    panels = [
        labelled(render_start_state(env_id, view, width, height), env_id)
        for env_id, view in VIEWS.items()
    ]
    strip = PILImage.new("RGB", (width * len(panels), height))
    for i, panel in enumerate(panels):
        strip.paste(panel, (i * width, 0))
    return strip


def save_small_png(image: Image, path: Path, colors: int = 256) -> None:
    """A palette PNG, a quarter of the RGB file's size: renders are smooth gradients that
    compress poorly. Octree keeps the small saturated objects (cubes, goal dot) that median
    cut merges into the greys of the robot and floor."""
    from PIL import Image as PILImage

    image.quantize(colors=colors, method=PILImage.Quantize.FASTOCTREE).save(path, optimize=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", type=Path, help="folder for h1hand_tasks.png")
    parser.add_argument("--width", type=int, default=300, help="width of one task's panel")
    parser.add_argument("--height", type=int, default=380, help="height of the strip")
    args = parser.parse_args(argv)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    path = args.out_dir / "h1hand_tasks.png"
    save_small_png(task_strip(args.width, args.height), path)
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KB)")


if __name__ == "__main__":
    main()
