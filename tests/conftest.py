import os
import sys
from pathlib import Path

# Offscreen rendering without a display; set before mujoco is imported anywhere.
os.environ.setdefault("MUJOCO_GL", "egl")

ROOT = Path(__file__).resolve().parent.parent
# The project is a set of top-level scripts, importable from the repository root.
sys.path.insert(0, str(ROOT))

# submitit (imported by sweep.py) runs logging.config.dictConfig at its first import, which closes
# every logging handler already made, and absl's (rliable imports absl.logging) holds the stream
# that was sys.stderr when it was made: pytest's capture file. A test importing sweep after one
# importing analyze then closed pytest's own capture ("I/O operation on closed file"; with
# tests/test_protocol.py before tests/test_sweep_fakes.py, say). Importing it first, before any
# handler exists, makes the order of the test files irrelevant.
import submitit  # noqa: E402, F401
