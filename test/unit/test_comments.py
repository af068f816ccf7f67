"""The package's comments explain the code as it is: no machine names, no timings, no run history.

Measurements and their history live in bench/README.md, the docs and the
commit messages, where they carry their date and machine; a comment that
says "took 3 s here" or names a CPU is stale the day the machine or the code
changes. The law list lives in the registry, not in docstrings. This reads
every comment and docstring of ``attitude_sil/`` (tokenize and ast; nothing
is imported).
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "attitude_sil"

_UNIT = r"(?:ns|us|µs|ms|s|sec|min)"
_FIGURE = r"\d[\d.,]*(?:-\d[\d.,]*)?\s?" + _UNIT + r"\b"
#: (what the rule keeps out, pattern) over comment and docstring text
RULES = (
    ("a machine name", re.compile(r"\b(?:EPYC|Xeon|Ryzen|Threadripper|AVX-?512|AVX2?|SSE4|rocketlake|skylake|"
                                  r"icelake|machine class|on this CPU)\b", re.I)),
    ("a timing of the code", re.compile(r"\d[\d.,]*\s?(?:ns|us|µs)\b")),
    ("a timing of the code", re.compile(r"\b(?:took|cost|costs|spent|saves|saved)\b[^.;\n]{0,30}?" + _FIGURE)),
    ("a measurement 'here'", re.compile(_FIGURE + r"[^.;\n]{0,25}\bhere\b|\bmeasured here\b", re.I)),
    ("run history", re.compile(r"\b\d+ (?:\w+ )?runs? (?:in|of) \d+\b")),
    ("a hand-kept list of the laws", re.compile(r"``pid``,\s+``fuzzy_pid``")),
)


def comment_texts(source: str) -> list[tuple[int, str]]:
    """(line, text) of every comment and docstring of a module's source."""
    out = [(tok.start[0], tok.string) for tok in tokenize.generate_tokens(io.StringIO(source).readline)
           if tok.type == tokenize.COMMENT]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                out.append((node.body[0].lineno, " ".join(doc.split())))
    return out


def findings(source: str, where: str) -> list[str]:
    """Each rule a comment or docstring of ``source`` breaks, as ``where:line: rule: 'match'``."""
    return [f"{where}:{line}: {what}: {m.group(0)!r}"
            for line, text in comment_texts(source) for what, rule in RULES for m in rule.finditer(text)]


def test_comments_hold_no_machine_names_timings_or_history():
    found = [x for path in sorted(PACKAGE.rglob("*.py")) for x in findings(path.read_text(), path.name)]
    assert not found, "move these to bench/README.md, the docs or a commit message:\n" + "\n".join(found)


def test_the_rules_see_what_they_are_for():
    bad = '''"""Runs on an AMD EPYC with AVX2."""
x = 1  # took 3.5 s here
# 16-24 ms here, on each start
def f():
    """A call costs 20 us; 1 hostile run in 4 failed."""
'''
    kinds = [x.split(": ")[1] for x in findings(bad, "t")]
    assert kinds.count("a machine name") == 2 and "run history" in kinds
    assert "a timing of the code" in kinds and "a measurement 'here'" in kinds
    good = '''"""The noise is sampled at 1 ms; a 0.1 s status period of sim time; the law saturates at 0.8 N m."""
# the electrical time constant L/R = 1 ms (assumed)
'''
    assert findings(good, "t") == []
