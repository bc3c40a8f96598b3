"""Files written whole or not at all, read without a half-written last line (a process may be
killed at any moment). No torch here: sweep.py's processes import it."""

import json
import os
from collections.abc import Callable
from pathlib import Path


def atomic_write(path: Path, write: Callable[[Path], object]) -> None:
    """Writes via a temporary file and os.replace: a kill leaves the old file or the new one."""
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def write_text_atomically(path: Path, text: str) -> None:
    """path holds its old content or `text`, synced before the rename (a power loss, too)."""
    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    atomic_write(path, write)


def write_json(path: Path, data: dict) -> None:
    """data as indented JSON, written as write_text_atomically writes."""
    write_text_atomically(path, json.dumps(data, indent=2) + "\n")


def read_json_object(path: Path, fix: str = "", error: type[Exception] = ValueError) -> dict:
    """A JSON file's object; else `error` (one line) naming what is wrong with it, then `fix`."""
    then = f"; {fix}" if fix else ""
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as problem:
        raise error(f"{path} is not valid JSON ({problem}){then}") from None
    if not isinstance(value, dict):
        raise error(f"{path} does not hold a JSON object{then}")
    return value


def complete_lines(path: Path) -> list[str]:
    """The file's lines with their ends (csv's \\r\\n); a last line a kill cut short is not one."""
    with path.open(newline="") as f:
        return [line for line in f.read().splitlines(keepends=True) if line.endswith("\n")]
