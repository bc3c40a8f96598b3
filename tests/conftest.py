import os
import sys
from pathlib import Path

# Offscreen rendering without a display; set before mujoco is imported anywhere.
os.environ.setdefault("MUJOCO_GL", "egl")

ROOT = Path(__file__).resolve().parent.parent
# The project is a set of top-level scripts, importable from the repository root.
sys.path.insert(0, str(ROOT))
