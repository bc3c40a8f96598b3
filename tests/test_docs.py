"""The README and the pages in docs/ hold together.

- Every picture they show is a file of the repository (in docs/, or a results figure in results/)
  that opens as an image; the pictures in docs/ stay small.
- Every relative link resolves to a file or folder of the repository, and every `#anchor` to a
  heading of its target page (GitHub's slugs).
- Every `--flag` they show for one of our scripts is a flag that script accepts (read from its
  `--help`); a flag shown without naming a program must be accepted by one of them.
- The task picture's renderer still works.
"""

import functools
import os
import re
import shlex
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from humanoid_envs.render import VIEWS, render_start_state

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# Markdown images ![alt](path "title") and HTML <img src="path">.
IMAGE_LINK = re.compile(
    r"!\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)"  # markdown
    r"|<img[^>]*\ssrc=\"([^\"]+)\""  # html
)
# Markdown links and images, [text](target "title"); the text may hold one level of brackets.
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^ {0,3}(```|~~~)")
CODE_SPAN = re.compile(r"`([^`]+)`")
HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")
FLAG = re.compile(r"(?<![\w-])--[a-z0-9][a-z0-9-]*")
# The pictures in docs/ are the ones the repository carries for the README alone: a few hundred
# KB in all, since the repository is cloned far more often than they change. A results figure
# (results/<campaign>/report-*/) is part of that campaign's record, committed with it whether or
# not a page shows it, so showing it costs nothing more and it has no cap here.
MAX_DOCS_PICTURE_BYTES = 400_000
PICTURE_FOLDERS = ("docs", "results")

# Our scripts, whose flags the pages must get right, as their --help lists them.
SCRIPTS = ("sac_standard.py", "sac_corrected.py", "evaluate.py", "analyze.py", "sweep.py")
# Subcommands with flags of their own: their --help's flags count as the script's.
SUBCOMMANDS = {"sweep.py": ("restart",)}
# Arguments after a standalone `--` on a sweep.py command go to the training script.
SWEEP_PASSES_TO = "sac_corrected.py"
# Flags that the pages show on their own (a code span without the program's name) but that
# belong to other programs: the flag, its program, and a word its source must contain (None:
# the pages say the flag is gone).
OTHER_FLAGS = {
    "--quick": ("bench/bench_gpu.py", "quick"),
    "--parts": ("bench/bench_gpu.py", "parts"),
    "--concurrent": ("bench/bench_gpu.py", None),  # "the benchmark as it was before --num-seeds"
    "--num-seeds": ("sac_standard.py", None),  # "until issue 37 the scripts could also ..."
    "--runs": ("docs/make_figures.py", '"--runs"'),
    "--no-build-isolation": ("pip", None),
}


def page_name(page: Path) -> str:
    return str(page.relative_to(ROOT))


def without_fences(text: str) -> tuple[list[str], list[str]]:
    """(prose lines, code-block lines) of a markdown text."""
    prose, code, fenced = [], [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        (code if fenced else prose).append(line)
    return prose, code


def images(page: Path) -> list[str]:
    prose, _ = without_fences(page.read_text())
    return [markdown or html for markdown, html in IMAGE_LINK.findall("\n".join(prose))]


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: no markup, lower case, no punctuation, spaces to -."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading).replace("`", "")
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


@functools.cache
def anchors(page: Path) -> frozenset[str]:
    prose, _ = without_fences(page.read_text())
    seen: Counter[str] = Counter()
    found = set()
    for line in prose:
        if match := HEADING.match(line):
            base = slug(match.group(2))
            found.add(base if seen[base] == 0 else f"{base}-{seen[base]}")
            seen[base] += 1
    return frozenset(found)


def links(page: Path) -> list[str]:
    """Link targets outside code blocks and code spans."""
    prose, _ = without_fences(page.read_text())
    return LINK.findall(CODE_SPAN.sub("", "\n".join(prose)))


def test_the_pages_are_there() -> None:
    assert len(PAGES) > 1, "docs/ holds no page"
    readme = (ROOT / "README.md").read_text()
    for page in PAGES[1:]:
        assert f"(docs/{page.name})" in readme, f"the README does not link {page_name(page)}"


@pytest.mark.parametrize("page", PAGES, ids=page_name)
def test_every_image_a_page_links_exists_in_the_repository(page: Path) -> None:
    for link in images(page):
        assert not SCHEME.match(link), f"{link}: images are files in the repository, not URLs"
        path = (page.parent / link).resolve()
        assert path.is_file(), f"{page_name(page)} links {link}, which does not exist"
        assert any(path.is_relative_to(ROOT / folder) for folder in PICTURE_FOLDERS), (
            f"{link}: keep the pictures in docs/ (or show a figure of results/)"
        )
        with Image.open(path) as image:
            image.verify()


def test_the_readme_shows_pictures() -> None:
    assert images(ROOT / "README.md"), "the README links no image"


def test_the_pictures_in_docs_are_small() -> None:
    shown = {(page.parent / link).resolve() for page in PAGES for link in images(page)}
    total = sum(path.stat().st_size for path in shown if path.is_relative_to(ROOT / "docs"))
    assert total <= MAX_DOCS_PICTURE_BYTES, f"the pictures in docs/ take {total / 1e3:.0f} KB"


@pytest.mark.parametrize("page", PAGES, ids=page_name)
def test_every_relative_link_resolves(page: Path) -> None:
    targets = links(page)
    assert targets or page.name != "README.md", "the README links nothing"
    for target in targets:
        if SCHEME.match(target):
            continue
        path_part, _, fragment = target.partition("#")
        path = (page.parent / path_part).resolve() if path_part else page
        where = f"{page_name(page)} links {target}"
        assert path.is_relative_to(ROOT), f"{where}, outside the repository"
        assert path.exists(), f"{where}, which does not exist"
        if fragment:
            assert path.suffix == ".md", f"{where}: an anchor in a file that is not markdown"
            assert fragment in anchors(path), (
                f"{where}, but {page_name(path)} has no heading with that anchor "
                f"(it has: {', '.join(sorted(anchors(path)))})"
            )


def test_slugs_are_githubs() -> None:
    assert slug("`mode_search.py`: the density of the squashed action") == (
        "mode_searchpy-the-density-of-the-squashed-action"
    )
    assert slug("Checkpoints, resume, signals") == "checkpoints-resume-signals"
    assert slug("Running the paper's experiment") == "running-the-papers-experiment"


@functools.cache
def accepted_flags() -> dict[str, frozenset[str]]:
    """Each script's flags, from the option lines of its --help and its subcommands' (tyro:
    `--cuda, --no-cuda`)."""
    env = {**os.environ, "COLUMNS": "200"}
    calls = [(script, ()) for script in SCRIPTS]
    calls += [(script, (sub,)) for script, subs in SUBCOMMANDS.items() for sub in subs]
    procs = {
        (script, sub): subprocess.Popen(
            [sys.executable, script, *sub, "--help"],
            cwd=ROOT,
            env=env,
            text=True,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        for script, sub in calls
    }
    option_line = re.compile(
        r"^[\s│|]{0,3}(?:-[a-zA-Z], )?(--[a-z0-9][a-z0-9-]*(?:, --[a-z0-9][a-z0-9-]*)*)"
    )
    flags: dict[str, frozenset[str]] = {}
    for (script, sub), proc in procs.items():
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, f"{script} --help failed: {err[-2000:]}"
        found = set()
        for line in out.splitlines():
            if match := option_line.match(line):
                found.update(match.group(1).split(", "))
        assert "--help" in found and len(found) > (1 if sub else 5), \
            f"read no options from {script} {' '.join(sub)} --help:\n{out}"
        flags[script] = flags.get(script, frozenset()) | found
    return flags


def tokens(command: str) -> list[str]:
    try:
        return shlex.split(command)
    except ValueError:  # an unbalanced quote in a fragment
        return command.split()


def program(words: list[str]) -> tuple[str | None, list[str]]:
    """The program a command runs (None: no program, a bare fragment) and its arguments."""
    while words and re.fullmatch(r"[A-Z_][A-Z0-9_]*=\S*", words[0]):  # MUJOCO_GL=egl ...
        words = words[1:]
    if words and re.fullmatch(r"(\S*/)?python[0-9.]*", words[0]):
        words = words[1:]
        if words[:1] == ["-m"] and len(words) > 1:
            return words[1], words[2:]
    if words and re.fullmatch(r"[\w./-]+\.py|[a-z][\w.-]*", words[0]):
        return words[0], words[1:]
    return None, words


def commands(page: Path) -> list[tuple[str, str]]:
    """(command, where) for every code block line and code span of a page (continued lines,
    ending in a backslash, joined; comments and chains, &&, ||, ;, |, split off), and the flags
    of its plain text."""
    prose, code = without_fences(page.read_text())
    joined = "\n".join(code).replace("\\\n", " ")
    pieces = [(line, "code block") for line in joined.splitlines()]
    pieces += [(span, "code span") for span in CODE_SPAN.findall("\n".join(prose))]
    # Plain text is no command: its flags are checked as a bare fragment's.
    pieces += [(" ".join(FLAG.findall(CODE_SPAN.sub("", "\n".join(prose)))), "text")]
    found = []
    for text, where in pieces:
        text = text.replace("\n", " ")
        command, hash_, comment = (
            text.partition(" #") if not text.lstrip().startswith("#") else ("", "#", text)
        )
        if hash_:
            found.append((comment, f"{where} (comment)"))
        found += [(part, where) for part in re.split(r"&&|\|\||;|\|", command)]
    return [(command.strip(), where) for command, where in found if FLAG.search(command)]


def flags_of(command: str) -> list[tuple[str | None, str]]:
    """(script whose flag it is, or None for any; flag) for each flag a command shows; flags of
    programs other than ours are not returned."""
    name, args = program(tokens(command))
    if name is None:
        return [(None, flag) for flag in FLAG.findall(command)]
    script = Path(name).name
    if script not in SCRIPTS:
        return []
    out = []
    for arg in args:
        if arg == "--" and script == "sweep.py":
            script = SWEEP_PASSES_TO
        elif match := FLAG.match(arg.lstrip("{[(")):
            out.append((script, match.group(0)))
    return out


@pytest.mark.parametrize("page", PAGES, ids=page_name)
@pytest.mark.slow
def test_every_flag_a_page_shows_is_accepted(page: Path) -> None:
    accepted = accepted_flags()
    anywhere = set().union(*accepted.values()) | set(OTHER_FLAGS)
    wrong = []
    for command, where in commands(page):
        for script, flag in flags_of(command):
            ok = flag in (accepted[script] if script else anywhere)
            if not ok:
                whose = script or "any of our scripts"
                wrong.append(f"{flag} ({whose}) in {where}: {command}")
    assert not wrong, f"{page_name(page)} shows flags that do not exist:\n" + "\n".join(wrong)


def test_the_other_programs_flags_are_theirs() -> None:
    for flag, (path, word) in OTHER_FLAGS.items():
        if word is not None:
            assert word in (ROOT / path).read_text(), f"{path} no longer has {flag}"


def test_the_flag_reader_reads_commands() -> None:
    assert flags_of(".venv/bin/python sweep.py --workers 2 -- --total-timesteps 20000") == [
        ("sweep.py", "--workers"),
        ("sac_corrected.py", "--total-timesteps"),
    ]
    assert flags_of("python bench/bench_gpu.py --quick") == []
    assert flags_of("evaluate.py run --selectors mode") == [("evaluate.py", "--selectors")]
    assert flags_of("--eval-episodes 10") == [(None, "--eval-episodes")]
    assert flags_of("--analyze-args='--reps 2000'") == [(None, "--analyze-args"), (None, "--reps")]


def test_every_task_has_a_view_and_renders_the_scene() -> None:
    import humanoid_envs

    assert set(VIEWS) == set(humanoid_envs.ENVS)
    frame = render_start_state("h1hand-stand-v0", VIEWS["h1hand-stand-v0"], 96, 120)
    assert frame.shape == (120, 96, 3) and frame.dtype == np.uint8
    assert frame.std() > 10.0
