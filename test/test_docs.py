"""The reference names exactly the CLI flags and node parameters the code declares.

docs/cli.md has one ``## `verb` `` section per verb with one flag table row per option
(``| `-o`, `--output` | ...``); every ``--flag`` in an inline code span of a section belongs to that verb, and every command line (``quad-modelling VERB ...`` or a span
starting with a verb name) names flags of its verb, in any file. docs/nodes.md has one
``### node`` section per parameter list, with one ``| `parameter` |`` table row per parameter;
``ros2 run quad_modelling NODE ... -p name:=value`` lines name parameters of NODE.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from quad_modelling.cli import build_parser
from quad_modelling.nodes.evaluator_node import EVALUATOR_PARAMETERS
from quad_modelling.nodes.predictor_node import predictor_parameters
from quad_modelling.nodes.replay_node import REPLAY_PARAMETERS
from test.conftest import REPO

CLI_DOC = REPO / "docs" / "cli.md"
NODES_DOC = REPO / "docs" / "nodes.md"
README = REPO / "README.md"

NODE_PARAMETERS = {
    "replay": {p.name for p in REPLAY_PARAMETERS},
    "predictor": {p.name for p in predictor_parameters("naive")},
    "greybox_predictor": {p.name for p in predictor_parameters("greybox")},
    "narx_predictor": {p.name for p in predictor_parameters("narx")},
    "evaluator": {p.name for p in EVALUATOR_PARAMETERS},
}
"""Declared parameters of every node executable (the Param lists the nodes declare)."""

FLAG = re.compile(r"(?<![\w-])(--?[A-Za-z][\w-]*)")
CODE_SPAN = re.compile(r"`([^`\n]+)`")
VERB_HEADING = re.compile(r"^## `([a-z][a-z-]*)`\s*$")
NODE_HEADING = re.compile(r"^### ([a-z_]+)\s*$")
PARAMETER_ROW = re.compile(r"^\| `([a-z_]+)` \|")
ROS2_RUN = re.compile(r"ros2 run quad_modelling (\w+)(.*)")
ROS_PARAMETER = re.compile(r"-p ([a-z_]+):=")


def verb_parsers(parser: argparse.ArgumentParser | None = None) -> dict[str, argparse.ArgumentParser]:
    parser = parser or build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(subparsers.choices)


def parser_flags(parser: argparse.ArgumentParser) -> set[str]:
    """Every option string of a verb, --help excepted (argparse's own)."""
    return {o for a in parser._actions if not isinstance(a, argparse._HelpAction) for o in a.option_strings}


def code_units(text: str) -> list[tuple[str, str]]:
    """(code, verb section or "") for every inline code span and every line of a fenced block."""
    units, section, fenced = [], "", False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            units.append((line, section))
            continue
        heading = VERB_HEADING.match(line)
        if heading:
            section = heading.group(1)
        elif line.startswith("#"):
            section = ""
        units.extend((span, section) for span in CODE_SPAN.findall(line))
    return units


def named_flags(text: str, verbs) -> tuple[dict[str, set[str]], set[str]]:
    """Flags named per verb (by section or command line), and flags named with no verb."""
    command = re.compile(r"(?:^|quad-modelling\s+)(" + "|".join(sorted(map(re.escape, verbs), key=len, reverse=True)) + r")(?![\w-])(.*)")
    per_verb: dict[str, set[str]] = {v: set() for v in verbs}
    loose: set[str] = set()
    for code, section in code_units(text):
        match = command.search(code.strip().removeprefix("$ "))
        if match:
            per_verb[match.group(1)] |= set(FLAG.findall(match.group(2)))
        elif section:
            per_verb[section] |= set(FLAG.findall(code))
        else:
            loose |= set(FLAG.findall(code))
    return per_verb, loose


def section_lines(text: str, heading: re.Pattern) -> dict[str, list[str]]:
    """The lines of each section whose heading matches ``heading`` (group 1 = its name), up to the next heading."""
    sections: dict[str, list[str]] = {}
    current = None
    for line in text.splitlines():
        match = heading.match(line)
        if match:
            current = sections.setdefault(match.group(1), [])
        elif line.startswith("#"):
            current = None
        elif current is not None:
            current.append(line)
    return sections


def flag_rows(text: str) -> dict[str, set[str]]:
    """Flags in the first cell of the flag table rows (``| `-o`, `--output` | ...``) of each verb section."""
    return {verb: {flag for line in lines if line.startswith("| `-") for flag in FLAG.findall(line.split("|")[1])}
            for verb, lines in section_lines(text, VERB_HEADING).items()}


def flag_mismatches(text: str, parsers: dict[str, argparse.ArgumentParser]) -> dict[str, dict[str, set[str]]]:
    """Per verb: flags the text names that the parser lacks ("unknown"), and parser flags without a
    row in the verb's flag table ("undocumented")."""
    per_verb, _ = named_flags(text, parsers)
    rows = flag_rows(text)
    return {verb: {"unknown": per_verb[verb] - parser_flags(p), "undocumented": parser_flags(p) - rows.get(verb, set())}
            for verb, p in parsers.items()}


def documented_parameters(text: str) -> dict[str, set[str]]:
    """Parameter table rows per ``### node`` section."""
    return {node: {row.group(1) for line in lines if (row := PARAMETER_ROW.match(line))}
            for node, lines in section_lines(text, NODE_HEADING).items()}


def ros_run_parameters(text: str) -> list[tuple[str, str]]:
    """(executable, parameter) for every ``-p name:=`` of a ``ros2 run quad_modelling`` line."""
    return [(m.group(1), name) for line in text.splitlines() if (m := ROS2_RUN.search(line))
            for name in ROS_PARAMETER.findall(m.group(2))]


def test_every_documented_flag_exists_and_every_flag_is_documented():
    parsers = verb_parsers()
    text = CLI_DOC.read_text()
    assert sorted(VERB_HEADING.match(line).group(1) for line in text.splitlines() if VERB_HEADING.match(line)) == sorted(parsers)
    mismatches = flag_mismatches(text, parsers)
    assert {verb: m for verb, m in mismatches.items() if m["unknown"] or m["undocumented"]} == {}
    _, loose = named_flags(text, parsers)
    all_flags = set().union(*(parser_flags(p) for p in parsers.values())) | {"--help"}
    assert loose - all_flags == set()


def test_readme_commands_use_existing_flags():
    parsers = verb_parsers()
    per_verb, _ = named_flags(README.read_text(), parsers)  # flags of other programs (pip) are not checked
    assert {verb: flags - parser_flags(parsers[verb]) for verb, flags in per_verb.items() if flags - parser_flags(parsers[verb])} == {}
    assert per_verb["run-bag"] >= {"--models", "--window", "--train", "--eval", "-o"}  # the tour's run-bag line was parsed


def test_node_executables_match_setup_py():
    scripts = re.findall(r'"(\w+) = quad_modelling\.node_entry:(\w+)"', (REPO / "setup.py").read_text())
    assert all(name == function for name, function in scripts)
    assert sorted(name for name, _ in scripts) == sorted(NODE_PARAMETERS)


def test_every_documented_parameter_is_declared_and_every_parameter_is_documented():
    sections = documented_parameters(NODES_DOC.read_text())
    assert sorted(sections) == ["evaluator", "predictor", "replay"]
    for node, documented in sections.items():
        assert documented == NODE_PARAMETERS[node], node
    # greybox_predictor and narx_predictor are documented with the generic predictor: same parameters
    assert NODE_PARAMETERS["greybox_predictor"] == NODE_PARAMETERS["narx_predictor"] == NODE_PARAMETERS["predictor"]


@pytest.mark.parametrize("doc", [NODES_DOC, README])
def test_ros_run_lines_set_declared_parameters(doc: Path):
    uses = ros_run_parameters(doc.read_text())
    assert [(node, name) for node, name in uses if name not in NODE_PARAMETERS.get(node, set())] == []
    if doc == NODES_DOC:
        assert ("greybox_predictor", "realtime_priority") in uses and ("evaluator", "output_dir") in uses


def test_a_removed_or_undocumented_flag_is_reported():
    text = CLI_DOC.read_text()
    parser = build_parser()
    parsers = verb_parsers(parser)
    parsers["evaluate"].add_argument("--undocumented-flag", action="store_true")
    removed = next(a for a in parsers["train"]._actions if "--hybrid" in a.option_strings)
    parsers["train"]._remove_action(removed)
    for option in removed.option_strings:
        del parsers["train"]._option_string_actions[option]
    mismatches = flag_mismatches(text, parsers)
    assert mismatches["evaluate"] == {"unknown": set(), "undocumented": {"--undocumented-flag"}}
    assert mismatches["train"] == {"unknown": {"--hybrid"}, "undocumented": set()}
    assert all(not m["unknown"] and not m["undocumented"] for verb, m in mismatches.items() if verb not in ("evaluate", "train"))


def test_a_flag_without_its_table_row_is_undocumented():
    text = CLI_DOC.read_text()
    without_row = "\n".join(line for line in text.splitlines() if not line.startswith("| `--quiet` |"))
    assert "--quiet" in without_row  # still named in the synopsis
    assert flag_mismatches(without_row, verb_parsers())["train"] == {"unknown": set(), "undocumented": {"--quiet"}}


def test_a_parameter_row_is_tied_to_its_section():
    text = "### replay\n\n| parameter | default |\n|---|---|\n| `bag` | required |\n| `rate` | 1.0 |\n\n## Next\n| `loose` | x |\n"
    assert documented_parameters(text) == {"replay": {"bag", "rate"}}
    assert ros_run_parameters("ros2 run quad_modelling evaluator --ros-args -p output_dir:=/tmp -p nice:=0") == [
        ("evaluator", "output_dir"), ("evaluator", "nice")]


LINK = re.compile(r"\]\(([^)\s]+)\)")


def heading_anchors(text: str) -> set[str]:
    """GitHub's anchors of a Markdown file's headings: lower case, punctuation dropped, spaces -> '-'."""
    anchors = set()
    for line in text.splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            anchors.add(re.sub(r"[^\w\- ]", "", title).replace(" ", "-"))
    return anchors


def test_relative_links_reach_files_and_headings():
    docs = [README, REPO / "bench" / "README.md", *sorted((REPO / "docs").glob("*.md"))]
    broken = []
    for doc in docs:
        for target in LINK.findall(doc.read_text()):
            if "://" in target:
                continue
            path, _, anchor = target.partition("#")
            resolved = (doc.parent / path) if path else doc
            if not resolved.exists() or (anchor and anchor not in heading_anchors(resolved.read_text())):
                broken.append(f"{doc.relative_to(REPO)} -> {target}")
    assert broken == []
    assert heading_anchors("## Executors, DDS profile, garbage collector\n### `run-bag`") == {
        "executors-dds-profile-garbage-collector", "run-bag"}
