"""Every command line the README and docs/ give for a launch script parses with that script's
parser: a renamed or newly required option shows here, not on a user's machine."""

import importlib
import re
import shlex
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
COMMAND = re.compile(r"^python -m (launch_scripts\.[a-z_]+|perception\.track)\b(.*)$", re.S)
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
            if m and m.group(2).strip() and not SYNOPSIS.search(m.group(2)):
                found.append((doc.name, m.group(1), m.group(2).strip()))
    return found


COMMANDS = documented_commands()


def test_the_docs_give_command_lines_to_check():
    modules = {module for _, module, _ in COMMANDS}
    assert len(COMMANDS) >= 60 and {"launch_scripts.trials", "perception.track", "launch_scripts.perception_service",
                                     "launch_scripts.planner_service", "launch_scripts.publish_frames"} <= modules


@pytest.mark.parametrize("doc, module, arguments", COMMANDS, ids=[f"{d}:{m} {a}"[:90] for d, m, a in COMMANDS])
def test_a_documented_command_line_parses(doc, module, arguments, capsys):
    script = importlib.import_module("launch_scripts.track" if module == "perception.track" else module)
    if not hasattr(script, "build_parser"):
        pytest.skip(f"{module} builds its parser inside main")
    try:
        script.build_parser().parse_args(shlex.split(arguments))
    except SystemExit as stop:
        if stop.code:  # 0: --help
            pytest.fail(f"{doc}: python -m {module} {arguments}: {capsys.readouterr().err.strip()}")
