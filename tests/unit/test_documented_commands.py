"""Every command line the README and docs/ give for a launch script or a benchmark parses with
that script's parser: a renamed or newly required option shows here, not on a user's machine
(nor in a figure's command that no longer reproduces it)."""

import importlib
import re
import shlex
from pathlib import Path

import pytest

from tests.benchmark_scripts import load_benchmark

REPO = Path(__file__).resolve().parents[2]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
COMMAND = re.compile(r"^python (?:-m (launch_scripts\.[a-z_]+|perception\.track)|(benchmarks/[a-z_]+\.py))\b(.*)$", re.S)
#: usage lines ("[--frames EP]", "{sim,sequence}", "SEQ ...") show a command's shape, not a command
SYNOPSIS = re.compile(r"[\[\]{}|<>]|\.\.\.")


def documented_commands() -> list[tuple[str, str, str]]:
    """(document, module, arguments) of each command line in a fenced code block (one per line,
    backslash continuations joined, comments dropped) or inline code span of the docs."""
    found = []
    for doc in DOCS:
        text = doc.read_text()
        blocks = re.findall(r"^```[^\n]*\n(.*?)^```", text, re.S | re.M)
        prose = re.sub(r"^```[^\n]*\n.*?^```", "", text, flags=re.S | re.M)
        lines = [line for block in blocks for line in block.replace("\\\n", " ").splitlines()]
        lines += [" ".join(span.split()) for span in re.findall(r"`([^`]+)`", prose)]
        for line in lines:
            m = COMMAND.match(line.split(" #")[0].strip().removesuffix("&").strip())
            if m and not SYNOPSIS.search(m.group(3)) and (m.group(2) or m.group(3).strip()):
                found.append((doc.name, m.group(1) or m.group(2), m.group(3).strip()))
    return found


COMMANDS = documented_commands()


def test_the_docs_give_command_lines_to_check():
    modules = {module for _, module, _ in COMMANDS}
    assert len(COMMANDS) >= 80 and {"launch_scripts.trials", "perception.track", "launch_scripts.perception_service",
                                     "launch_scripts.planner_service", "launch_scripts.publish_frames",
                                     "benchmarks/bench_tracker.py", "benchmarks/real_recordings.py"} <= modules


def _script(module: str):
    """The module of ``python -m MODULE`` or of ``python benchmarks/NAME.py`` (not a package)."""
    if module.endswith(".py"):
        return load_benchmark(Path(module).stem)
    return importlib.import_module("launch_scripts.track" if module == "perception.track" else module)


@pytest.mark.parametrize("doc, module, arguments", COMMANDS, ids=[f"{d}:{m} {a}"[:90] for d, m, a in COMMANDS])
def test_a_documented_command_line_parses(doc, module, arguments, capsys):
    try:
        _script(module).build_parser().parse_args(shlex.split(arguments))
    except SystemExit as stop:
        if stop.code:  # 0: --help
            pytest.fail(f"{doc}: {module} {arguments}: {capsys.readouterr().err.strip()}")
