"""Every command and sample output the README and the guides show comes from a real run.

Two kinds of fenced block are checked:

* ``console`` blocks are transcripts: a line ``$ attitude-sil ...`` (or
  ``$ python ...``, a program of the examples, with the venv's interpreter) is a
  command, the lines after it (to the next ``$``) what it prints on stdout (on
  stderr where it fails: the one-line error). The test runs each command as a
  user would, from a fresh folder holding the repository's ``config/`` and
  ``examples/``, and compares. Values that differ from run to run (wall
  times, rates, the date in a bag's name, the ROS domain, a bag's size in
  bytes) are masked on both sides (:data:`VOLATILE`); every other character
  must match, except that a decimal number may differ by one unit of its last
  printed digit (numpy's math kernels differ by CPU: :func:`same_number`). A
  line ``...`` stands for any number of lines. A command
  ending in ``&`` runs in the background for the commands after it (the
  graph a ``param`` call talks to) and is stopped at the end of the block.
* ``bash`` blocks are commands only: every ``attitude-sil`` line is parsed by
  the real command-line parser, and every ``config/`` or ``examples/`` file
  it names must exist.

A transcript that no longer matches fails with the output of today's run:
``UPDATE_DOC_SAMPLES=1 pytest test/cli/test_doc_samples.py`` writes it into the
guide (then restore any ``...`` elision by hand and read the diff).
"""

from __future__ import annotations

import difflib
import functools
import os
import re
import shlex
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from attitude_sil.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BIN = Path(sys.executable).parent

#: what differs between two runs of the same command, masked before comparing: (pattern, replacement)
VOLATILE = (
    (re.compile(r"(wall time\s+)\d[\d.]* s"), r"\1<wall> s"),
    (re.compile(r"(real-time factor\s+)\d[\d.]* x"), r"\1<rtf> x"),
    (re.compile(r"\b\d[\d.]* (evals|runs)/s\b"), r"<rate> \1/s"),
    (re.compile(r"\bin \d[\d.]* s\b"), "in <wall> s"),
    (re.compile(r"_\d{8}_\d{6}\b"), "_<date>"),
    (re.compile(r"ROS_DOMAIN_ID=\d+"), "ROS_DOMAIN_ID=<domain>"),
    (re.compile(r"(Bag size:\s+)\S+ \S+"), r"\1<size>"),
    (re.compile(r"\(\d+ worker\(s\)\)"), "(<n> worker(s))"),
    (re.compile(r"(controller latency \w+\s+)\d[\d.e+-]* ms"), r"\1<latency> ms"),
)


@dataclass
class Block:
    path: Path
    line: int  # 1-based line of the opening fence
    lang: str
    text: str
    steps: list = field(default_factory=list)  # (command, expected lines) for a transcript

    @property
    def id(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def _blocks(lang: str) -> list[Block]:
    out = []
    for path in DOCS:
        text = path.read_text()
        for m in re.finditer(r"^```(\w*)\n(.*?)^```", text, re.S | re.M):
            if m.group(1) == lang:
                out.append(Block(path, text[:m.start()].count("\n") + 1, lang, m.group(2)))
    return out


def _transcripts() -> list[Block]:
    blocks = _blocks("console")
    for b in blocks:
        for line in b.text.splitlines():
            if line.startswith("$ "):
                b.steps.append((line[2:], []))
            elif b.steps:
                b.steps[-1][1].append(line)
            else:
                raise AssertionError(f"{b.id}: a console block starts with a '$ ' command")
    return blocks


def normalize(text: str) -> list[str]:
    """The lines of ``text`` with :data:`VOLATILE` values masked and trailing blanks dropped."""
    lines = []
    for line in text.splitlines():
        for pattern, repl in VOLATILE:
            line = pattern.sub(repl, line)
        lines.append(line.rstrip())
    while lines and not lines[-1]:
        lines.pop()
    return lines


#: a number in a line of output: an integer, a decimal, or either with an exponent
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def same_number(expected: str, actual: str) -> bool:
    """Whether ``actual`` prints the value ``expected`` does, as another CPU computes it.

    Integers (counts, indices, paper numbers) must be equal. A decimal may
    differ by one unit of its last printed digit, or by 1e-9 of its value
    where it is printed in full: numpy picks its exp, log and pow kernels by
    CPU (AVX-512 where there is one, AVX2 elsewhere), which moves the last
    bits of a result and so, at a rounding boundary, a printed digit.
    """
    if not re.search(r"[.eE]", expected):
        return expected == actual
    if not re.search(r"[.eE]", actual):
        return False
    mantissa, _, exponent = expected.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    unit = 10.0 ** (int(exponent or 0) - decimals)
    e, a = float(expected), float(actual)
    return abs(a - e) <= max(unit * (1 + 1e-9), 1e-9 * abs(e))


def same_line(expected: str, actual: str) -> bool:
    """The two lines' text equal and their numbers the same (:func:`same_number`)."""
    if expected == actual:
        return True
    exp_numbers, act_numbers = NUMBER.findall(expected), NUMBER.findall(actual)
    return (NUMBER.split(expected) == NUMBER.split(actual) and len(exp_numbers) == len(act_numbers)
            and all(same_number(e, a) for e, a in zip(exp_numbers, act_numbers, strict=True)))


def matches(expected: list[str], actual: list[str]) -> bool:
    """``actual`` line for line like ``expected`` (:func:`same_line`), where a line ``...`` of ``expected``
    stands for any number of lines."""
    @functools.cache
    def rest(i: int, j: int) -> bool:
        if i == len(expected):
            return j == len(actual)
        if expected[i] == "...":
            return rest(i + 1, j) or (j < len(actual) and rest(i, j + 1))
        return j < len(actual) and same_line(expected[i], actual[j]) and rest(i + 1, j + 1)

    return rest(0, 0)


def _workdir(tmp_path: Path) -> Path:
    # a user's checkout: the shipped config and examples, and room for bags/ and results/ of its own
    for name in ("config", "examples"):
        (tmp_path / name).symlink_to(ROOT / name)
    return tmp_path


def _argv(command: str) -> list[str]:
    # attitude-sil, or python (the venv's) for a program of the examples
    argv = shlex.split(command)
    assert argv[0] in ("attitude-sil", "python"), f"a transcript runs attitude-sil or python, got {command!r}"
    return [str(BIN / "attitude-sil") if argv[0] == "attitude-sil" else sys.executable, *argv[1:]]


@pytest.mark.parametrize("block", _transcripts(), ids=lambda b: b.id)
def test_transcript_is_what_the_command_prints(block, tmp_path):
    cwd = _workdir(tmp_path)
    env = dict(os.environ, COLUMNS="120")
    background = []
    got = []
    failures = []
    try:
        for command, expected in block.steps:
            got.append(f"$ {command}")
            if command.endswith("&"):
                background.append(subprocess.Popen(_argv(command[:-1]), cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                                                   stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True))
                continue
            proc = subprocess.run(_argv(command), cwd=cwd, env=env, capture_output=True, text=True, timeout=240,
                                  stdin=subprocess.DEVNULL)
            shown = proc.stdout if proc.returncode == 0 else proc.stdout + proc.stderr
            got.extend(shown.rstrip("\n").splitlines() if shown.strip() else [])
            if not matches(normalize("\n".join(expected)), normalize(shown)):
                diff = "\n".join(difflib.unified_diff(normalize("\n".join(expected)), normalize(shown),
                                                      "guide", "run", lineterm=""))
                failures.append(f"$ {command}  (exit {proc.returncode})\n{diff}\n{proc.stderr[-2000:]}")
    finally:
        for p in background:
            p.send_signal(signal.SIGINT)
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
    if failures and os.environ.get("UPDATE_DOC_SAMPLES"):
        text = block.path.read_text()
        text = text.replace(block.text, "\n".join(got) + "\n", 1)
        block.path.write_text(text)
    assert not failures, f"{block.id}: the guide's transcript is not what today's run prints:\n" + "\n".join(failures)


def _command_lines() -> list[tuple[str, str]]:
    out = []
    for b in _blocks("bash"):
        for i, raw in enumerate(b.text.replace("\\\n", " ").splitlines()):
            line = raw.split(" #", 1)[0].strip().rstrip("&").strip()
            words = shlex.split(line) if line else []
            while words and re.fullmatch(r"[A-Z_]+=\S*", words[0]):
                words.pop(0)  # VAR=value before the command
            if words and Path(words[0]).name == "attitude-sil":
                out.append((f"{b.id}+{i + 1}", line))
    return out


@pytest.mark.parametrize("where,line", _command_lines(), ids=lambda x: x if ":" in x else "")
def test_shown_command_parses_and_names_shipped_files(where, line):
    words = shlex.split(line)
    while re.fullmatch(r"[A-Z_]+=\S*", words[0]):
        words.pop(0)
    args = [re.sub(r"<[^>]+>", "X", w) for w in words[1:]]  # placeholders (<run>, <printed>) stand for a value
    try:
        build_parser().parse_args(args)
    except SystemExit as exc:
        pytest.fail(f"{where}: `{line}` is refused by today's parser (exit {exc.code})")
    for word in args:
        if re.match(r"(config|examples)/", word):
            assert (ROOT / word).exists(), f"{where}: `{line}` names {word}, which the repository does not ship"


def test_the_checks_see_the_guides():
    # the collection itself: a renamed fence or a moved guide must not leave the guides unchecked
    assert len(_transcripts()) >= 6
    assert len(_command_lines()) >= 30


def test_normalize_masks_only_what_varies():
    run = "  wall time                1.60 s\n  settling time            9.68 s\n  bag   bags/hst_20261122_015801\n"
    assert normalize(run) == ["  wall time                <wall> s", "  settling time            9.68 s",
                              "  bag   bags/hst_<date>"]
    assert matches(["a", "...", "d"], ["a", "b", "c", "d"]) and matches(["a", "...", "d"], ["a", "d"])
    assert not matches(["a", "...", "d"], ["a", "b", "c"]) and not matches(["a", "b"], ["a", "c"])


def test_a_number_may_move_by_its_last_printed_digit_and_no_more():
    # what an AVX-512 machine printed against the guides written on an AVX2 one
    assert matches(["overshoot [%]   2   0.01114   PASS"], ["overshoot [%]   2   0.01115   PASS"])
    assert matches(["ki: [1.1779736606617848e-05]"], ["ki: [1.1779736606035238e-05]"])
    assert matches(["n: 16.391744691028766"], ["n: 16.39174469102877"])
    # a real change is not hidden: two units, a relative 1e-7 in full print, an integer, the text around
    assert not matches(["overshoot [%]   2   0.01114   PASS"], ["overshoot [%]   2   0.01116   PASS"])
    assert not matches(["ki: [1.1779736606617848e-05]"], ["ki: [1.1779737806617848e-05]"])
    assert not matches(["after 2000 evaluations"], ["after 2001 evaluations"])
    assert not matches(["cost 0.5129 PASS"], ["cost 0.5129 FAIL"]) and not matches(["x 1.5"], ["x 15"])
    assert not matches(["a 1.0 b"], ["a 1.0 b 2"])
