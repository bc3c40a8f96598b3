"""The README's pictures exist, stay small, and the task picture's renderer still works."""

import re
from pathlib import Path

import numpy as np
from PIL import Image

from humanoid_envs.render import VIEWS, render_start_state

ROOT = Path(__file__).resolve().parent.parent
# Markdown images ![alt](path "title") and HTML <img src="path">.
IMAGE_LINK = re.compile(
    r"!\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)"  # markdown
    r"|<img[^>]*\ssrc=\"([^\"]+)\""  # html
)
# A few hundred KB in all: the repository is cloned far more often than the pictures change.
MAX_TOTAL_BYTES = 400_000


def readme_images() -> list[str]:
    text = (ROOT / "README.md").read_text()
    return [markdown or html for markdown, html in IMAGE_LINK.findall(text)]


def test_every_image_the_readme_links_exists_in_the_repository() -> None:
    links = readme_images()
    assert links, "the README links no image"
    for link in links:
        assert "://" not in link, f"{link}: images are files in the repository, not URLs"
        path = (ROOT / link).resolve()
        assert path.is_file(), f"README links {link}, which does not exist"
        assert path.is_relative_to(ROOT / "docs"), f"{link}: keep the pictures in docs/"
        with Image.open(path) as image:
            image.verify()


def test_the_pictures_are_small() -> None:
    total = sum((ROOT / link).stat().st_size for link in set(readme_images()))
    assert total <= MAX_TOTAL_BYTES, f"README pictures take {total / 1e3:.0f} KB"


def test_every_task_has_a_view_and_renders_the_scene() -> None:
    import humanoid_envs

    assert set(VIEWS) == set(humanoid_envs.ENVS)
    frame = render_start_state("h1hand-stand-v0", VIEWS["h1hand-stand-v0"], 96, 120)
    assert frame.shape == (120, 96, 3) and frame.dtype == np.uint8
    assert frame.std() > 10.0
