"""The README's five-minute tour, run as written: every ``$ ...`` line of it, in order, in a fresh directory (the
repository's ``bags/`` linked in, as in a fresh clone), each command's output checked against the lines the README
shows for it, so the README cannot drift from the CLI again.

Shape check: the README shows real output trimmed to the telling lines (not every cut marked: ``...`` marks one inside
a line or of many lines, long lines are wrapped, tables are padded to their widths). Each shown line must appear in the
command's output, after the line shown before it, with whitespace collapsed, every number a wildcard (timings, domain
ids and the last digits of scores are not the README's to fix) and a table rule's dashes of any length: the words,
names, units, columns and their order must match.

Cost: the tour itself, nothing shortened for the test: 45 s of CPU (user + sys, the run-bag nodes and Dask workers
included); wall 56 s here at a load average of 6 on 2 cores, 49 s inside a full-suite run, 105-125 s at a load average of
8-12 (run-bag and diagnose about 20 s each of it).
"""

from __future__ import annotations

import json
import os
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from quad_modelling.cli import main
from test.conftest import REPO

NUMBER = r"-?(?:\d+(?:\.\d*)?|\.\d+)(?:e[+-]?\d+)?"
"""Any number the CLI prints (integer, decimal, exponent)."""


@dataclass
class TourStep:
    """One ``$`` line of the tour and the output lines the README shows under it."""

    command: str
    shown: list[str] = field(default_factory=list)


def tour_steps(readme: str) -> list[TourStep]:
    """The ``$`` lines of the README's tour (between "## A five-minute tour" and the next section), in order, each with
    the lines shown under it in its code block."""
    tour = readme[readme.index("## A five-minute tour"):]
    tour = tour[:tour.index("\n## ", 1)]
    steps: list[TourStep] = []
    inside, current = False, None
    for line in tour.splitlines():
        if line.startswith("```"):
            inside, current = not inside, None  # a block without a $ line (a command to type elsewhere) is not run
            continue
        if not inside:
            continue
        if line.startswith("$ "):
            current = TourStep(line[2:].strip())
            steps.append(current)
        elif current is not None:
            current.shown.append(line)
    return steps


def shape_pattern(lines: list[str]) -> re.Pattern:
    """The regular expression of shown lines: whitespace collapsed, numbers and a table rule's dashes wildcards."""
    text = " ".join(" ".join(lines).split())
    parts = []
    for token in re.split(rf"(\.\.\.|{NUMBER}|-{{3,}}| )", text):
        if not token:
            continue
        if token == "...":  # a cut inside a line ("fig_z.png, ...")
            parts.append(".*?")
        elif token == " ":
            parts.append(r"\s+")
        elif re.fullmatch(NUMBER, token):
            parts.append(NUMBER)
        elif re.fullmatch(r"-{3,}", token):
            parts.append(r"-{3,}")
        else:
            parts.append(re.escape(token))
    return re.compile("".join(parts))


def check_shape(step: TourStep, output: str) -> None:
    """Every line shown under a command appears in its output, in the order shown (module docstring)."""
    text = " ".join(output.split())
    position = 0
    for line in step.shown:
        if not line.strip() or line.strip() == "...":
            continue
        match = shape_pattern([line]).search(text, position)
        assert match, f"$ {step.command}: the README shows\n{line}\nnot found (in this order) in its output:\n{output}"
        position = match.end()


def run_step(step: TourStep, capsys) -> str:
    """Run one ``$`` line in the current directory: ``mkdir`` as the shell does, ``quad-modelling`` through the CLI's
    entry point; the command's stdout and stderr."""
    argv = shlex.split(step.command, comments=True)
    if argv[0] == "mkdir":
        for directory in (a for a in argv[1:] if not a.startswith("-")):
            os.makedirs(directory, exist_ok="-p" in argv)
        return ""
    assert argv[0] == "quad-modelling", f"the tour runs quad-modelling and mkdir only, not: {step.command}"
    capsys.readouterr()
    code = main(argv[1:])
    captured = capsys.readouterr()
    assert code == 0, f"$ {step.command} exited {code}: {captured.err}"
    return captured.out + captured.err


def test_the_readme_tour_makes_every_file_it_reads_and_the_shape_check_is_strict():
    steps = tour_steps((REPO / "README.md").read_text())
    assert [s.command.split()[:2] for s in steps][:2] == [["mkdir", "tour"], ["quad-modelling", "simulate"]]
    made = {"tour"}
    for step in steps:  # a fresh clone has no tour/: every tour/ path a line reads is made by an earlier line
        words = shlex.split(step.command, comments=True)
        output = words[words.index("-o") + 1] if "-o" in words else None
        read = [w for w in words[1:] if w.startswith("tour/") and w != output]
        assert all(path in made for path in read), (step.command, read, made)
        made |= {output} if output else {words[-1]}
    pattern = shape_pattern(["| a  | b  |", "|----|---:|", "x 1.5e+03 / 0.2 s"])
    assert pattern.fullmatch("| a | b | |---|------:| x 2 / 0.25 s")
    assert not pattern.fullmatch("| a | c | |---|------:| x 2 / 0.25 s") and not pattern.fullmatch("| a | b | |---|------:| x 2 / 0.25 ms")
    assert shape_pattern(["-> out/ (a.json, b.png, ...)"]).fullmatch("-> out/ (a.json, b.png, c.png, d.png)")


@pytest.mark.slow  # every command of the README's tour, as written (about 30 s): `make test-slow`
def test_the_readme_tour_runs_as_written_from_a_fresh_directory(tmp_path, monkeypatch, capsys):
    (tmp_path / "bags").symlink_to(REPO / "bags")
    monkeypatch.chdir(tmp_path)
    steps = tour_steps((REPO / "README.md").read_text())
    made = []
    for step in steps:
        check_shape(step, run_step(step, capsys))
        made.append(step.command)
    assert len(made) == len(steps) >= 12
    assert (tmp_path / "tour" / "diag" / "report.md").is_file()
    # "Every number of the two results.json is the same, bit for bit": the --jobs 2 fleet and the merge of its parts
    fleet, merged = (json.loads((tmp_path / "tour" / name / "results.json").read_text()) for name in ("fleet", "merged"))
    for key in ("models", "windows", "horizons", "statistics"):
        assert fleet[key] == merged[key], key
