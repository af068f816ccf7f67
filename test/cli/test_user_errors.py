"""Every user error is one line: a generated table of bad input fed to ``attitude-sil``.

The table is built in code (``pytest.mark.parametrize`` over a list) rather
than drawn by Hypothesis: the bad inputs form a known catalogue (every
parameter of the schema times the ways its kind can be wrong, every structural
way a file can be broken, every flag times NaN/inf/negative/garbage), so a
table covers all of it deterministically, names each case in pytest's output,
needs no new dependency, and costs a known, bounded time (Hypothesis would draw
a random subset and shrink failures we can name directly).

Each case runs ``attitude_sil.cli.main(argv)`` in this process and asserts: exit
code 2, exactly one line on stderr (``attitude-sil...: error: ...``) naming the
problem, no traceback, nothing on stdout. Bad input must be refused before any
ROS context, graph or simulation starts: the fixture makes ``rclpy.init``,
``GraphSession.__enter__`` and the long computations raise :class:`Started`, so a
value accepted by mistake fails its case instead of running. The domain
announcement is forced on (as a user without ``ROS_DOMAIN_ID`` sees it), so
refusing input after announcing the domain fails too (two lines). A handful of
subprocess cases check the real process, and the tune signal tests check that
Ctrl-C and SIGTERM stop a tuning run with one line and keep its results.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from geometry_msgs.msg import QuaternionStamped
from rclpy.serialization import serialize_message

from attitude_sil.cli import common as cli_common
from attitude_sil.cli import main
from attitude_sil.core.sim.params import GLOBAL_NODE, NODE_PARAMS, ParamSpec
from attitude_sil.graph.session import GraphSession
from attitude_sil.storage import BagWriter
from attitude_sil.tuning import executor, fidelity, linearize, montecarlo, robustness
from conftest import CONFIG, ROOT

SCENARIO = str(CONFIG / "hst_roll_step.yaml")
SPEC_TEXT = (CONFIG / "tune_hst_pid_ga.yaml").read_text().replace("scenarios: [", f"scenarios: [{CONFIG}/")
DIR = object()  # a files entry that is a directory
GARBAGE = bytes(range(256)) * 4 + b"\x89PNG\r\n\x1a\n\x00\xff\xfe"


REAL_INIT = rclpy.init


class Started(BaseException):
    """Bad input got past validation: a ROS context, a graph or a long computation would start."""


# ------------------------------------------------------------------ the table
def _case(id_, argv, files=None, needles=(), bag=False, late=False):
    """``late``: found only while the command runs (a corrupt chunk met mid-replay), so ROS may start."""
    return pytest.param(argv, files or {}, needles, bag, late, id=id_)


def _yaml(value) -> str:
    if isinstance(value, float) and math.isnan(value):
        return ".nan"
    if isinstance(value, float) and math.isinf(value):
        return ".inf" if value > 0 else "-.inf"
    if isinstance(value, list):
        return "[" + ", ".join(_yaml(v) for v in value) + "]"
    if isinstance(value, str):
        return json.dumps(value)
    return str(value)


def _bad_numbers(spec: ParamSpec) -> list[tuple[str, str]]:
    """(label, YAML text) of numbers this spec must refuse."""
    out = [("nan", ".nan"), ("1e400", "1e400"), ("-inf", "-.inf")]
    if spec.kind.startswith("integer"):
        out += [("fraction", "1.5"), ("2^70", str(2**70))]
    if spec.min is not None:
        low = spec.min if spec.min_exclusive else spec.min - 1
        out.append(("below-min", _yaml(int(low) if spec.kind.startswith("integer") else float(low))))
    if spec.max is not None:
        out.append(("above-max", _yaml(spec.max + 1 if spec.kind.startswith("integer") else spec.max * 2 + 1)))
    return out


def _bad_values(spec: ParamSpec) -> list[tuple[str, str]]:
    """(label, YAML text) of values of every kind of wrong for one parameter."""
    kind = spec.kind
    if kind in ("double", "integer"):
        return [("string", '"fast"'), ("list", "[1.0]"), ("mapping", "{a: 1}"), ("null", "null"), ("bool", "true"),
                *_bad_numbers(spec)]
    if kind == "bool":
        return [("int", "3"), ("string", '"maybe"'), ("null", "null"), ("list", "[true]")]
    if kind == "string":
        out = [("int", "3"), ("list", "[a]"), ("mapping", "{a: 1}"), ("null", "null")]
        return out + ([("choice", "nope"), ("empty", '""')] if spec.choices else [])
    if kind == "string_array":
        out = [("scalar", '"x"'), ("int-element", "[3]"), ("nested", "[[a]]"), ("mapping", "{a: 1}")]
        return out + ([("choice-element", "[nope]")] if spec.choices else [])
    # numeric arrays
    n = spec.lengths[0] if spec.lengths else 3
    good = spec.default if len(spec.default) == n else [spec.min + 1 if spec.min is not None else 1] * n

    def with_element(text: str) -> str:
        return "[" + ", ".join([text] + [_yaml(v) for v in good[1:]]) + "]"

    out = [("scalar", "1.0"), ("string", '"1, 2, 3"'), ("mapping", "{a: 1}"), ("nested", "[" + ", ".join(
        f"[{_yaml(v)}]" for v in good) + "]"), ("string-element", with_element('"x"')),
        ("null-element", with_element("null"))]
    out += [(f"element-{label}", with_element(text)) for label, text in _bad_numbers(spec)]
    if spec.lengths:
        out.append(("too-long", _yaml(list(good) + [good[0]] * (max(spec.lengths) + 1 - n))))
        if 0 not in spec.lengths:
            out.append(("empty", "[]"))
        if n > 1:
            out.append(("too-short", _yaml(list(good[:-1]))))
    return out


def _scenario_value_cases() -> list:
    """Every parameter of every node (once per name for shared ones) times its kind's wrong values."""
    cases, seen = [], set()
    for node, specs in NODE_PARAMS.items():
        if node == GLOBAL_NODE:
            continue
        for spec in specs:
            if spec.name in seen and node != "scenario":
                continue  # control_period, orbit.*, aero.*, inertia: one node's copy is enough
            seen.add(spec.name)
            for label, text in _bad_values(spec):
                body = f"{node}:\n  ros__parameters:\n    {spec.name}: {text}\n"
                cases.append(_case(f"scenario-{node}.{spec.name}-{label}", ["run", "{tmp}/s.yaml", "--no-record"],
                                   {"s.yaml": body}, ("s.yaml", f"{node}.{spec.name}")))
    return cases


def _section(node: str, **values) -> str:
    lines = "".join(f"    {k}: {v}\n" for k, v in values.items())
    return f"{node}:\n  ros__parameters:\n{lines}"


def _file_cases(command: list[str], name: str, what: str) -> list:
    """Ways a YAML file given to ``command`` can be broken (``{f}`` in command is the file)."""
    argv = [a.replace("{f}", "{tmp}/" + name) for a in command]
    bad = {
        "missing": None,
        "directory": DIR,
        "binary-garbage": GARBAGE,
        "latin1": "plant:\n  ros__parameters:\n    description: caf\xe9\n".encode("latin-1"),
        "nul-bytes": "plant: \x00\x01\n",
        "unclosed-list": "plant: [unclosed\n",
        "unclosed-quote": 'plant: "open\n',
        "bad-indent": "a:\n  b: 1\n c: 2\n",
        "tab-indent": "plant:\n\tros__parameters: {}\n",
        "double-colon": "a: b: c\n",
        "unhashable-key": "? [a, b]\n: 1\n",
        "deep-nesting": "[" * 5000 + "]" * 5000 + "\n",
        "top-list": "- plant\n- wheels\n",
        "top-scalar": "42\n",
        "top-string": "hello\n",
        "unknown-section": _section("plantt", duration=1.0),
        "section-list": "plant: [1, 2]\n",
        "section-scalar": "plant: 3\n",
        "section-extra-key": "plant:\n  ros__parameters: {}\n  other: 1\n",
        "parameters-list": "plant:\n  ros__parameters: [1, 2]\n",
        "unknown-key": _section("controller", **{"pid.kpp": "[1.0, 1.0, 1.0]"}),
    }
    cases = []
    for label, content in bad.items():
        files = {} if content is None else {name: content}
        cases.append(_case(f"{what}-{label}", argv, files, (name,)))
    return cases


def _scenario_structure_cases() -> list:
    cases = _file_cases(["run", "{f}", "--no-record"], "s.yaml", "scenario")
    cases.append(_case("scenario-empty-file", ["run", "{tmp}/s.yaml"], {"s.yaml": ""}, ("s.yaml",)))
    cross = {
        "control-period-differs": _section("plant", control_period=0.01) + _section("wheels", control_period=0.02),
        "duration-not-whole-steps": _section("plant", duration=1.005),
        "schedule-lengths": _section("scenario", **{"schedule.times": "[1.0, 2.0]",
                                                    "schedule.controller_types": "[pid]"}),
        "schedule-decreasing": _section("scenario", **{"schedule.times": "[2.0, 1.0]",
                                                       "schedule.controller_types": "[pid, ga_flc]"}),
        "inertia-zero": _section("plant", inertia="[0.0, 0.0, 0.0]"),
        "inertia-negative": _section("plant", inertia="[-1.0, 2.0, 3.0]"),
        "inertia-not-symmetric": _section("plant", inertia="[1.0, 0.5, 0, 0, 1.0, 0, 0, 0, 1.0]"),
        "inertia-indefinite": _section("plant", inertia="[1.0, 2.0, 0, 2.0, 1.0, 0, 0, 0, 1.0]"),
        "geometric-inertia-zero": _section("controller", **{"geometric.inertia": "[0.0, 0.0, 0.0]"}),
        "error-axis-zero": _section("plant", initial_error_axis="[0.0, 0.0, 0.0]", initial_error_deg=1.0),
        "wheel-speeds-length": _section("wheels", initial_speed_rpm="[1.0, 2.0]"),
        "noise-sample-time": _section("disturbance", models="[noise]", **{"noise.sample_time": 0.003}),
        "torque-actuator-voltage-law": _section("wheels", actuator="torque"),
        "speed-loop-torque-law": _section("wheels", actuator="speed_loop") + _section(
            "controller", controller_type="geometric"),
        "swap-to-law-actuator-refuses": _section("wheels", actuator="speed_loop") + _section(
            "scenario", **{"schedule.times": "[1.0]", "schedule.controller_types": "[geometric]"}),
        "duration-zero": _section("plant", duration=0.0),
        "global-bad-value": '"/**":\n  ros__parameters:\n    control_period: -1.0\n',
        "global-unknown": '"/**":\n  ros__parameters:\n    nope: 1\n',
    }
    for label, body in cross.items():
        cases.append(_case(f"scenario-{label}", ["run", "{tmp}/s.yaml", "--no-record"], {"s.yaml": body},
                           ("s.yaml",)))
    return cases


def _params_file_cases() -> list:
    cases = _file_cases(["run", SCENARIO, "--params", "{f}", "--no-record"], "p.yaml", "params")
    more = {
        "empty-file": "",
        "comment-only": "# nothing\n",
        "node-null": "controller: null\n",
        "bad-value-nan": _section("controller", **{"pid.kp": "[1.0, .nan, 1.0]"}),
        "short-vector": _section("controller", **{"pid.kp": "[1.0, 1.0]"}),
        "bad-choice": _section("controller", controller_type="bangbang"),
        "not-distinct": _section("controller", **{"geometric.k": "[1.0, 1.0, 2.0]"}),
        "duration-not-whole-steps": _section("plant", duration=1.005),
    }
    for label, body in more.items():
        cases.append(_case(f"params-{label}", ["run", SCENARIO, "--params", "{tmp}/p.yaml"], {"p.yaml": body},
                           ("p.yaml",)))
    cases += [_case(f"robustness-{label}", ["robustness", SCENARIO, "--params", "{tmp}/p.yaml"], {"p.yaml": body},
                    ("p.yaml",)) for label, body in [("garbage", GARBAGE), ("short-vector", more["short-vector"])]]
    cases.append(_case("verify-params-garbage", ["replay", "{tmp}/bag", "--verify-controller", "--params",
                                                 "{tmp}/p.yaml"], {"p.yaml": GARBAGE}, ("p.yaml",), bag=True))
    return cases


def _spec_cases() -> list:
    cases = _file_cases(["tune", "{f}"], "t.yaml", "spec")
    cases.append(_case("spec-empty-file", ["tune", "{tmp}/t.yaml"], {"t.yaml": ""}, ("t.yaml",)))
    lines = SPEC_TEXT.splitlines()

    def replace(key: str, text: str | None) -> str:
        out = [ln for ln in lines if not ln.startswith(f"{key}:")]
        if text is not None:
            out.append(f"{key}: {text}")
        return "\n".join(out) + "\n"

    mutations = {key: [(f"missing-{key}", None)] for key in ("scenarios", "controller", "genome", "cost", "algorithm")}
    mutations["unknown"] = [("unknown-key", "1")]
    mutations["scenarios"] += [("scenarios-empty", "[]"), ("scenarios-missing-file", "[nope.yaml]"),
                               ("scenarios-mapping", "{a: 1}"), ("scenarios-nested", "[[a]]"),
                               ("scenarios-directory", f"[{CONFIG}]"), ("scenarios-null", "null")]
    mutations["controller"] += [("controller-bogus", "bangbang"), ("controller-list", "[pid]")]
    genome = {
        "genome-empty": "[]", "genome-mapping": "{a: 1}", "genome-scalar": "3", "genome-entry-scalar": "[3]",
        "gene-missing-low": "[{param: pid.kp, high: 2.0}]", "gene-unknown-param": "[{param: pid.kq, low: 1, high: 2}]",
        "gene-not-array": "[{param: controller_type, low: 1, high: 2}]",
        "gene-low-string": "[{param: pid.kp, low: a, high: 2}]",
        "gene-low-list": "[{param: pid.kp, low: [1], high: 2}]",
        "gene-nan": "[{param: pid.kp, low: .nan, high: 2}]", "gene-inf": "[{param: pid.kp, low: 1, high: .inf}]",
        "gene-low-above-high": "[{param: pid.kp, low: 3, high: 2}]",
        "gene-below-range": "[{param: pid.ki, low: -1, high: 2}]",
        "gene-kind": "[{param: pid.kp, low: 1, high: 2, kind: complex}]",
        "gene-count-string": "[{param: pid.kp, low: 1, high: 2, count: a}]",
        "gene-count-list": "[{param: pid.kp, low: 1, high: 2, count: [1]}]",
        "gene-count-zero": "[{param: pid.kp, low: 1, high: 2, count: 0}]",
        "gene-count-fraction": "[{param: pid.kp, low: 1, high: 2, count: 1.5}]",
        "gene-count-huge": "[{param: pid.kp, low: 1, high: 2, count: 1000000000}]",
        "gene-bits-huge": "[{param: pid.kp, low: 1, high: 2, kind: bits, bits: 100}]",
        "gene-bits-string": "[{param: pid.kp, low: 1, high: 2, kind: bits, bits: x}]",
        "gene-index-negative": "[{param: pid.kp, low: 1, high: 2, index: -1}]",
        "gene-index-string": "[{param: pid.kp, low: 1, high: 2, index: a}]",
        "gene-index-too-large": "[{param: pid.kp, low: 1, high: 2, index: 3}]",
        "gene-unknown-key": "[{param: pid.kp, low: 1, high: 2, hgh: 3}]",
        "gene-final-time-string": "[{param: final_time, low: a, high: 2}]",
        "gene-final-time-kind": "[{param: final_time, low: 1, high: 2, kind: complex}]",
    }
    mutations["genome"] += list(genome.items())
    mutations["cost"] += [("cost-bogus", "{name: nope}"), ("cost-list", "[paper000_j]"), ("cost-null", "null"),
                          ("cost-unknown-key", "{name: paper000_j, bta: 1}"),
                          ("cost-beta-string", "{name: paper001_fitness, beta: a}"),
                          ("cost-limit-nan", "{name: paper001_fitness, limit: .nan}"),
                          ("cost-limit-negative", "{name: paper001_fitness, limit: -1}"),
                          ("cost-w1-list", "{name: paper004_objective, w1: [1]}")]
    mutations["algorithm"] += [("algorithm-bogus", "{name: nope}"), ("algorithm-list", "[ga]"),
                               ("algorithm-null", "null"), ("algorithm-unknown-key", "{name: ga, pop_sze: 4}"),
                               ("algorithm-pop-string", "{name: ga, pop_size: a}"),
                               ("algorithm-pop-one", "{name: ga, pop_size: 1}"),
                               ("algorithm-pop-huge", "{name: ga, pop_size: 10000000000}"),
                               ("algorithm-generations-negative", "{name: ga, generations: -3}"),
                               ("algorithm-generations-inf", "{name: ga, generations: .inf}"),
                               ("algorithm-crossover-string", "{name: ga, crossover: a}"),
                               ("algorithm-crossover-above-1", "{name: ga, crossover: 1.5}"),
                               ("algorithm-mutation-nan", "{name: ga, mutation: .nan}"),
                               ("algorithm-binary-needs-bits", "{name: binary_ga}"),
                               ("algorithm-nsga2-needs-ts-ce", "{name: nsga2}"),
                               ("algorithm-restarts-string", "{name: root_locus, restarts: a}")]
    mutations["conditions"] = [("conditions-scalar", "3"), ("conditions-list-of-scalars", "[1, 2]"),
                               ("conditions-unknown-param", "[{plant.nope: 1}]"),
                               ("conditions-unknown-node", "[{nope.duration: 1}]"),
                               ("conditions-no-dot", "[{plant: 1}]"),
                               ("conditions-bad-value", "[{plant.duration: .nan}]")]
    mutations["evaluation"] = [("evaluation-mode", "{mode: nope}"), ("evaluation-list", "[batch]"),
                               ("evaluation-string", "batch"), ("evaluation-workers-zero", "{workers: 0}"),
                               ("evaluation-workers-string", "{workers: a}"),
                               ("evaluation-workers-huge", "{workers: 100000}"),
                               ("evaluation-unknown-key", "{mode: batch, wrkers: 2}")]
    mutations["seed"] = [("seed-negative", "-1"), ("seed-string", "a"), ("seed-fraction", "1.5"),
                         ("seed-list", "[1]"), ("seed-huge", str(2**70))]
    mutations["output"] = [("output-list", "[a]"), ("output-mapping", "{a: 1}"),
                           ("output-under-file", f"{CONFIG / 'hst_roll_step.yaml'}/out")]
    mutations["record"] = [("record-list", "[1]"), ("record-string", "yes"),
                           ("record-unknown-key", "{best_per_generatoin: true}"),
                           ("record-best-string", "{best_per_generation: maybe}")]
    mutations["name"] = [("name-list", "[a]"), ("name-mapping", "{a: 1}")]
    for key, variants in mutations.items():
        for label, text in variants:
            cases.append(_case(f"spec-{label}", ["tune", "{tmp}/t.yaml"], {"t.yaml": replace(key, text)},
                               ("t.yaml",)))
    return cases


def _set_cases() -> list:
    spec = str(CONFIG / "tune_hst_pid_ga.yaml")
    bad = {
        "no-equals": ("seed", "KEY=VALUE"), "empty-key": ("=3", "--set"), "unknown-section": ("bogus.x=1", "bogus"),
        "unknown-top": ("bogus=1", "bogus"), "genome": ("genome=[]", "genome"),
        "seed-string": ("seed=abc", "seed"), "seed-list": ("seed=[1]", "seed"), "seed-negative": ("seed=-1", "seed"),
        "seed-fraction": ("seed=1.5", "seed"), "seed-nan": ("seed=.nan", "seed"), "seed-empty": ("seed=", "seed"),
        "seed-huge": (f"seed={2**70}", "seed"),
        "output-empty": ("output=", "output"), "output-list": ("output=[a]", "output"),
        "output-under-file": (f"output={CONFIG / 'hst_roll_step.yaml'}/out", "hst_roll_step.yaml"),
        "generations-zero": ("algorithm.generations=0", "algorithm.generations"),
        "generations-nan": ("algorithm.generations=.nan", "algorithm.generations"),
        "generations-string": ("algorithm.generations=many", "algorithm.generations"),
        "pop-fraction": ("algorithm.pop_size=1.5", "algorithm.pop_size"),
        "pop-huge": ("algorithm.pop_size=100000000000", "algorithm.pop_size"),
        "algorithm-name": ("algorithm.name=nope", "algorithm.name"),
        "algorithm-unknown": ("algorithm.bogus=1", "algorithm.bogus"),
        "crossover-string": ("algorithm.crossover=a", "algorithm.crossover"),
        "mutation-negative": ("algorithm.mutation=-1", "algorithm.mutation"),
        "cost-name": ("cost.name=nope", "cost.name"), "cost-unknown": ("cost.bogus=1", "cost.bogus"),
        "evaluation-mode": ("evaluation.mode=nope", "evaluation.mode"),
        "workers-zero": ("evaluation.workers=0", "evaluation.workers"),
        "workers-bool": ("evaluation.workers=true", "evaluation.workers"),
        "replicas-string": ("evaluation.replicas=a", "evaluation.replicas"),
        "record-best": ("record.best_per_generation=maybe", "record.best_per_generation"),
        "record-unknown": ("record.bogus=1", "record.bogus"),
        "yaml-malformed": ("seed=[1", "seed"), "yaml-garbage": ("cost.beta=\x00\x01", "cost.beta"),
    }
    return [_case(f"set-{label}", ["tune", spec, "--set", item], {}, (needle,))
            for label, (item, needle) in bad.items()]


def _number_flag_cases(command: list[str], flag: str, values: dict[str, str], needle: str, bag=False) -> list:
    return [_case(f"{' '.join(c for c in command[:1])}-{flag.strip('-')}-{label}", [*command, flag, v], {},
                  (needle,), bag) for label, v in values.items()]


NONFINITE = {"nan": "nan", "inf": "inf", "-inf": "-inf", "1e400": "1e400"}
GARBLED = {"string": "fast", "empty": ""}


def _flag_cases() -> list:
    run = ["run", SCENARIO, "--no-record"]
    cases = _number_flag_cases(run, "--duration", {**NONFINITE, **GARBLED, "negative": "-1", "zero": "0",
                                                   "not-whole-steps": "1.005"}, "duration")
    cases += _number_flag_cases(run, "--controller", {"bogus": "bangbang", "empty": ""}, "controller_type")
    cases += _number_flag_cases(run, "--swap", {"no-colon": "2.0", "bad-time": "x:pid", "nan-time": "nan:pid",
                                                "inf-time": "inf:pid", "negative-time": "-1:pid",
                                                "bad-type": "1:bangbang", "empty-type": "1:", "empty": ""}, "swap")
    cases += _number_flag_cases(run, "--namespace", {"space": "bad ns", "bang": "sat!", "digit": "1sat",
                                                     "double-slash": "a//b", "dash": "sat-1"}, "namespace")
    cases += [_case("run-record-under-file", [*run[:2], "--record", f"{SCENARIO}/bag"], {}, ("hst_roll_step.yaml",)),
              _case("run-record-existing-bag", [*run[:2], "--record", "{tmp}/bag"], {}, ("already contains",),
                    bag=True),
              _case("run-record-dot", [*run[:2], "--record", "."], {}, ("bag directory",)),
              _case("run-record-and-no-record", [*run, "--record", "x"], {}, ("not allowed with",)),
              _case("run-unknown-flag", [*run, "--durration", "3"], {}, ("unrecognized",)),
              _case("run-no-scenario", ["run"], {}, ("scenario",)),
              _case("no-command", [], {}, ("command",)),
              _case("unknown-command", ["rn", SCENARIO], {}, ("invalid choice",))]
    cases += _number_flag_cases(run, "--foxglove", {"zero": "0", "too-big": "70000", "string": "x",
                                                    "negative": "-1"}, "--foxglove")
    cases += [_case("run-foxglove-fast-alone", [*run, "--foxglove-fast"], {}, ("--foxglove",)),
              _case("run-foxglove-host-alone", [*run, "--foxglove-host", "127.0.0.1"], {}, ("--foxglove",)),
              _case("run-foxglove-host-not-here", [*run, "--foxglove", "8765", "--foxglove-host", "192.0.2.1"], {},
                    ("192.0.2.1",)),
              _case("run-wait-for-viewer-alone", [*run, "--wait-for-viewer", "5"], {}, ("--foxglove",)),
              # an optional value that looks like a flag is not taken as the value: named as an unknown argument
              _case("run-wait-for-viewer--inf", [*run, "--foxglove", "8765", "--wait-for-viewer", "-inf"], {},
                    ("-inf",))]
    # no value (or inf) is no limit; a limit must be seconds > 0
    cases += _number_flag_cases([*run, "--foxglove", "8765"], "--wait-for-viewer",
                                {"nan": "nan", **GARBLED, "negative": "-1", "zero": "0"}, "--wait-for-viewer")
    cases += [_case("record-no-bag", ["record"], {}, ("bag",)),
              _case("record-unknown-topic", ["record", "{tmp}/b", "--topics", "nope"], {}, ("nope",)),
              _case("record-topics-then-bag-unknown", ["record", "--topics", "nope", "{tmp}/b"], {}, ("nope",)),
              _case("record-namespace", ["record", "{tmp}/b", "--namespace", "bad ns"], {}, ("namespace",)),
              _case("record-existing-bag", ["record", "{tmp}/bag"], {}, ("already contains",), bag=True),
              _case("record-bag-under-file", ["record", f"{SCENARIO}/b"], {}, ("hst_roll_step.yaml",)),
              _case("record-episode-no-step-topic", ["record", "{tmp}/b", "--episode", "--topics",
                                                     "parameter_events"], {}, ("--episode",))]
    cases += _number_flag_cases(["episode"], "--timeout", {**NONFINITE, **GARBLED, "negative": "-1", "zero": "0"},
                                "timeout")
    cases += [_case("episode-namespace", ["episode", "--namespace", "sat-1"], {}, ("namespace",)),
              _case("episode-scenario-missing", ["episode", "--scenario", "{tmp}/none.yaml"], {}, ("none.yaml",)),
              _case("metrics-no-snapshot", ["metrics", "{tmp}/bag"], {}, ("--scenario",), bag=True),
              _case("metrics-scenario-missing", ["metrics", "{tmp}/bag", "--scenario", "{tmp}/none.yaml"], {},
                    ("none.yaml",), bag=True),
              _case("metrics-no-episode", ["metrics", "{tmp}/bag", "--scenario", SCENARIO], {}, ("no episode",),
                    bag=True)]
    cases += _file_cases(["metrics", "{tmp}/bag", "--scenario", "{f}"], "s.yaml", "metrics")[:3]
    tune = ["tune", str(CONFIG / "tune_hst_pid_ga.yaml")]
    cases += [_case("tune-unknown-flag", [*tune, "--bogus"], {}, ("unrecognized",)),
              _case("tune-resume-nothing", [*tune, "--resume", "--set", "output={tmp}/none"], {}, ("resume",))]
    rep = ["replay", "{tmp}/bag"]
    cases += _number_flag_cases(rep, "--rate", {**NONFINITE, **GARBLED, "negative": "-1"}, "rate", bag=True)
    cases += _number_flag_cases(rep, "--start", {**NONFINITE, "negative": "-1"}, "start", bag=True)
    cases += _number_flag_cases(rep, "--duration", {**NONFINITE, "negative": "-1", "zero": "0"}, "duration",
                                bag=True)
    cases += [_case("replay-unknown-topic", [*rep, "--topics", "nope"], {}, ("nope",), True),
              _case("replay-namespace", [*rep, "--namespace", "bad ns"], {}, ("namespace",), True)]
    ver = [*rep, "--verify-controller"]
    cases += [_case(f"verify-tolerance-{label}", [*ver, "--tolerance", v], {}, ("tolerance",), True)
              for label, v in {"nan": "nan", "negative": "-1", "inf": "inf", "string": "x"}.items()]
    cases.append(_case("verify-no-inputs", ver, {}, ("{tmp}/bag",), True))
    cases += [_case(f"plot-output-{label}", ["plot", "{tmp}/bag", "-o", out], {}, (needle,), True)
              for label, out, needle in [("extension", "{tmp}/x.xyz", "x.xyz"), ("no-extension", "{tmp}/x", "png"),
                                         ("directory", "{tmp}", "png"), ("under-file", f"{SCENARIO}/x.png", "x.png")]]
    cases += [_case(f"param-timeout-{label}", ["param", "list", "controller", "--timeout", v], {}, ("timeout",))
              for label, v in {**NONFINITE, "negative": "-1", "zero": "0", "string": "x"}.items()]
    cases += [_case(f"param-node-{label}", ["param", "list", node], {}, ("node",))
              for label, node in {"space": "bad node", "empty": "", "slash-end": "controller/"}.items()]
    cases += [_case("param-bad-action", ["param", "lst", "controller"], {}, ("invalid choice",)),
              _case("param-get-no-name", ["param", "get", "controller"], {}, ("required: name",)),
              _case("param-set-no-value", ["param", "set", "controller", "pid.kp"], {}, ("required: value",)),
              _case("param-name-bad", ["param", "get", "controller", "bad name!"], {}, ("bad name!",))]
    cases += [_case(f"fault-{label}", ["fault", *args], {}, (needle,))
              for label, args, needle in [("target", ["whel1", "lost"], "unknown target 'whel1'"),
                                          ("mode", ["wheel1", "off"], "a wheel cannot be 'off'"),
                                          ("latency-zero", ["star_tracker", "latency", "0"], "a latency must be > 0"),
                                          ("no-value", ["wheel1", "friction"], "needs a value"),
                                          ("value-nan", ["wheel1", "friction", "nan"], "must be finite"),
                                          ("namespace", ["wheel1", "lost", "--namespace", "a b"], "a b"),
                                          ("timeout", ["wheel1", "lost", "--timeout", "0"], "timeout")]]
    lin = ["linearize", SCENARIO]
    cases += [_case(f"linearize-angles-{label}", [*lin, "--angles", *v], {}, ("angle",))
              for label, v in {"nan": ["nan"], "inf": ["3", "inf"], "huge": ["1e6"], "negative-zero": ["0"],
                               "string": ["x"]}.items()]
    cases += [_case(f"linearize-gains-{label}", [*lin, "--gains", *v], {}, ("gains",))
              for label, v in {"nan": ["nan", "1", "1", "1"], "negative": ["1", "-1", "1", "1"],
                               "three": ["1", "1", "1"], "zero-n": ["1", "1", "1", "0"]}.items()]
    cases += [_case(f"linearize-duration-{label}", [*lin, "--duration", v], {}, ("duration",))
              for label, v in {"nan": "nan", "negative": "-1", "zero": "0"}.items()]
    cases.append(_case("linearize-flexible", ["linearize", str(CONFIG / "flexible_axis.yaml")], {}, ("rigid-body",)))
    cases += _file_cases(["linearize", "{f}"], "s.yaml", "linearize")[:3]
    cases += [_case("fidelity-paper-unknown", ["fidelity", "--paper", "005"], {}, ("invalid choice",)),
              _case("fidelity-paper-empty", ["fidelity", "--paper", ""], {}, ("invalid choice",)),
              _case("fidelity-config-missing", ["fidelity", "--config", "{tmp}/nowhere"], {}, ("not a folder",)),
              _case("fidelity-config-file", ["fidelity", "--config", SCENARIO], {}, ("not a folder",)),
              _case("fidelity-config-no-presets", ["fidelity", "--config", "{tmp}/d"], {"d": DIR},
                    ("missing preset", "hst_roll_step.yaml"))]
    return cases


def _bag_cases() -> list:
    """Broken bags for every command that reads one."""
    broken = {
        "missing": {},
        "empty-dir": {"b": DIR},
        "empty-file": {"b.mcap": b""},
        "garbage": {"b.mcap": GARBAGE},
        "magic-only": {"b.mcap": b"\x89MCAP0\r\n"},
        "half-magic": {"b.mcap": b"\x89MC"},
        "metadata-garbage": {"b/metadata.yaml": GARBAGE},
        "metadata-lists-missing": {"b/metadata.yaml":
                                   "rosbag2_bagfile_information:\n  relative_file_paths: [x.mcap]\n"},
        "dir-of-garbage": {"b/b_0.mcap": GARBAGE},
    }
    commands = {"info": ["bag", "info"], "plot": ["plot"], "replay": ["replay"], "verify": ["replay"],
                "metrics": ["metrics"]}
    cases = []
    for label, files in broken.items():
        target = "{tmp}/" + ("b" if not files or any(k.startswith("b/") or k == "b" for k in files) else "b.mcap")
        for cmd, prefix in commands.items():
            argv = [*prefix, target] + (["-o", "{tmp}/out.png"] if cmd == "plot" else []) + (
                ["--verify-controller"] if cmd == "verify" else [])
            cases.append(_case(f"bag-{cmd}-{label}", argv, files, ("{tmp}/b",)))
    for cmd in ("info", "plot", "replay"):  # (bag info reads the summary only: a corrupt chunk is not its business)
        cases.append(_case(f"bag-{cmd}-truncated-chunk", [*commands[cmd], "{tmp}/cut.mcap"] + (
            ["-o", "{tmp}/out.png"] if cmd == "plot" else []), {"cut.mcap": "CUT"}, ("cut.mcap",), True))
        if cmd != "info":
            cases.append(_case(f"bag-{cmd}-corrupt-chunk", [*commands[cmd], "{tmp}/bad.mcap", "--rate", "0"] if
                               cmd == "replay" else [*commands[cmd], "{tmp}/bad.mcap", "-o", "{tmp}/out.png"],
                               {"bad.mcap": "FLIP"}, ("bad.mcap",), True, late=cmd == "replay"))
    results = {"summary-garbage": {"r/summary.json": GARBAGE, "r/evaluations.jsonl": "{\"generation\": 1}\n"},
               "evaluations-garbage": {"r/evaluations.jsonl": "not json\n"},
               "evaluations-wrong-shape": {"r/evaluations.jsonl": "[1, 2]\n"},
               "summary-list": {"r/summary.json": "[1]", "r/evaluations.json": "[]"}}
    cases += [_case(f"plot-results-{label}", ["plot", "{tmp}/r", "-o", "{tmp}/out.png"], files, ("{tmp}/r",))
              for label, files in results.items()]
    return cases


MC_TEXT = (CONFIG / "mc_hst_roll_step.yaml").read_text().replace("scenario: ", f"scenario: {CONFIG}/")


def _montecarlo_cases() -> list:
    """The montecarlo command: its spec (file, keys, dispersions, requirements) and its flags."""
    cases = _file_cases(["montecarlo", "{f}"], "m.yaml", "mc")[:14]
    mc = ["montecarlo", "{tmp}/m.yaml"]

    def spec(old: str, new: str) -> dict:
        assert old in MC_TEXT, old
        return {"m.yaml": MC_TEXT.replace(old, new)}

    bad = {
        "unknown-key": ("runs: 1000", "runz: 1000", "runz"),
        "runs-zero": ("runs: 1000", "runs: 0", "runs"),
        "runs-string": ("runs: 1000", "runs: many", "runs"),
        "seed-negative": ("seed: 13", "seed: -1", "seed"),
        "chunk-zero": ("chunk: 100 ", "chunk: 0 ", "chunk"),
        "no-scenario": ("scenario: ", "scenarioo: ", "scenario"),
        "scenario-missing": ("hst_roll_step.yaml", "nope.yaml", "nope.yaml"),
        "set-unknown": ("disturbance.models: [noise]", "disturbance.modelz: [noise]", "modelz"),
        "set-bad-value": ("disturbance.models: [noise]", "disturbance.models: [wind]", "wind"),
        "controller": ("controller: pid", "controller: bangbang", "controller"),
        "dispersion-unknown": ("inertia_pct:", "inertia_pc:", "inertia_pc"),
        "dispersion-dist": ("{dist: normal, scale: [5.0, 5.0, 5.0]}", "{dist: cauchy, scale: 5}", "dist"),
        "dispersion-scale-negative": ("scale: [5.0, 5.0, 5.0]", "scale: [-5.0, 5.0, 5.0]", "scale"),
        "dispersion-scale-two": ("scale: [5.0, 5.0, 5.0]", "scale: [5.0, 5.0]", "scale"),
        "dispersion-scale-nan": ("scale: [5.0, 5.0, 5.0]", "scale: .nan", "scale"),
        "failure-probability": ("probability: 0.05", "probability: 1.5", "probability"),
        "failure-mode": ("modes: [lost, stuck]", "modes: [exploded]", "modes"),
        "failure-time": ("time: [2.0, 18.0]", "time: [18.0, 2.0]", "time"),
        "sensor-negative": ("attitude_std_deg: 0.0002", "attitude_std_deg: -1", "attitude_std_deg"),
        "noise-seeds-string": ("noise_seeds: true", "noise_seeds: yes please", "noise_seeds"),
        "requirement-unknown": ("settling_time_s: {max: 20.0}", "settling_tim_s: {max: 20.0}", "settling_tim_s"),
        "requirement-rule": ("settling_time_s: {max: 20.0}", "settling_time_s: {below: 20.0}", "settling_time_s"),
        "requirement-nan": ("settling_time_s: {max: 20.0}", "settling_time_s: {max: .nan}", "settling_time_s"),
        "worst-metric": ("worst: {metric: settling_time_s, count: 3}", "worst: {metric: speed, count: 3}", "worst"),
        "worst-count": ("worst: {metric: settling_time_s, count: 3}", "worst: {metric: settling_time_s, count: -1}",
                        "worst.count"),
        "plot-runs": ("plot: {runs: 100, stride: 10}", "plot: {runs: 100000, stride: 10}", "plot.runs"),
        "output-file": ("output: results/mc_hst_roll_step", f"output: {CONFIG}/hst_roll_step.yaml", "output"),
    }
    for label, (old, new, needle) in bad.items():
        cases.append(_case(f"mc-spec-{label}", mc, spec(old, new), (needle,)))
    hawaii = (CONFIG / "mc_hawaiisat_lvlh.yaml").read_text().replace("scenario: ", f"scenario: {CONFIG}/")
    cases += [_case("mc-spec-failure-on-torque-rods", mc, {"m.yaml": hawaii.replace(
                  "dispersions:\n", "dispersions:\n  wheel_failure: {probability: 0.1}\n")}, ("reaction_wheels",)),
              _case("mc-spec-motor-on-torque-rods", mc, {"m.yaml": hawaii.replace(
                  "dispersions:\n", "dispersions:\n  motor_constant_pct: {scale: 3}\n")}, ("reaction_wheels",)),
              _case("mc-spec-noise-level-without-noise", mc, {"m.yaml": hawaii.replace(
                  "dispersions:\n", "dispersions:\n  noise_level_pct: {scale: 3}\n")}, ("noise",))]
    good_text = MC_TEXT.replace("output: results/mc_hst_roll_step", "output: /nonexistent-attitude-sil/out")
    good = {"m.yaml": good_text}
    flags = _number_flag_cases(mc, "--runs", {"zero": "0", "negative": "-5", "string": "x", "float": "2.5"}, "runs")
    flags += _number_flag_cases(mc, "--workers", {"zero": "0", "negative": "-1", "string": "x"}, "workers")
    flags += _number_flag_cases(mc, "--scheduler", {"no-scheme": "127.0.0.1:8786", "http": "http://h:1",
                                                    "no-port": "tcp://127.0.0.1", "bad-port": "tcp://h:99999",
                                                    "empty": "", "garbage": "!!"}, "scheduler")
    cases += [pytest.param(c.values[0], good, *c.values[2:], id=c.id) for c in flags]  # a good spec, a bad flag
    cases += [_case("mc-resume-nothing", [*mc, "--resume"], good, ("resume",)),
              _case("mc-scheduler-and-in-process", [*mc, "--in-process", "--scheduler", "tcp://127.0.0.1:1"], good,
                    ("not allowed with",)),
              _case("mc-unknown-flag", [*mc, "--bogus"], good, ("unrecognized",)),
              _case("tune-scheduler-garbage", ["tune", str(CONFIG / "tune_hst_pid_ga.yaml"), "--scheduler", "x"], {},
                    ("scheduler",))]
    return cases


CASES = (_scenario_value_cases() + _scenario_structure_cases() + _params_file_cases() + _spec_cases()
         + _set_cases() + _flag_cases() + _bag_cases() + _montecarlo_cases())


# ------------------------------------------------------------------ fixtures
def _write_bag(path: Path, with_snapshot: bool = False) -> Path:
    """A small valid bag: 50 attitude messages in several chunks (no graph, no snapshot)."""
    writer = BagWriter(path, chunk_size=512)
    writer.add_topic("/attitude", "geometry_msgs/msg/QuaternionStamped")
    for k in range(50):
        msg = QuaternionStamped()
        msg.header.stamp.nanosec = k * 10_000_000
        msg.header.frame_id = "inertial"
        msg.quaternion.w = 1.0
        writer.write("/attitude", serialize_message(msg), k * 10_000_000)
    writer.close()
    return path


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory) -> Path:
    return _write_bag(tmp_path_factory.mktemp("good") / "bag")


@pytest.fixture
def no_start(monkeypatch):
    """Make anything past validation fail the case, and announce the domain as a user without one sees it."""
    def started(*args, **kwargs):
        raise Started()

    monkeypatch.setattr(rclpy, "init", started)
    monkeypatch.setattr(GraphSession, "__enter__", started)
    monkeypatch.setattr(linearize, "simulate", started)
    monkeypatch.setattr(robustness, "simulate", started)
    # the verbs import these when they run (attitude_sil/cli/<verb>.py execute): patch them where they live
    monkeypatch.setattr(montecarlo, "run_campaign", started)
    monkeypatch.setattr(executor, "make_executor", started)
    monkeypatch.setattr(fidelity, "simulate", started)
    monkeypatch.setattr(cli_common, "isolated_domain", lambda: (77, True))


def _materialise(tmp: Path, files: dict, good: Path) -> None:
    for name, content in files.items():
        path = tmp / name
        path.parent.mkdir(parents=True, exist_ok=True)
        mcap = (good / "bag_0.mcap").read_bytes()
        if content is DIR:
            path.mkdir()
        elif content == "CUT":  # cut inside a chunk: a torn copy whose first chunk is incomplete too
            path.write_bytes(mcap[:40])
        elif content == "FLIP":  # a chunk's compressed bytes overwritten: CRC or zstd fails
            data = bytearray(mcap)
            data[200:260] = b"\xa5" * 60
            path.write_bytes(bytes(data))
        else:
            path.write_bytes(content if isinstance(content, bytes) else content.encode())


@pytest.mark.parametrize("argv,files,needles,bag,late", CASES)
def test_bad_input_is_one_line(argv, files, needles, bag, late, tmp_path, good_bag, capsys, monkeypatch, no_start):
    if late:
        monkeypatch.setattr(rclpy, "init", REAL_INIT)
    if bag:
        _write_bag(tmp_path / "bag")
    _materialise(tmp_path, files, good_bag)
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    except Started:
        pytest.fail(f"accepted: {argv} got past validation")
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err and lines[0].startswith("attitude-sil") and "error: " in lines[0], err
    for needle in needles:
        assert needle.replace("{tmp}", str(tmp_path)) in lines[0], lines[0]
    assert out == "", out


# ------------------------------------------------------------------ real processes
def _cli(*args, env=None, timeout=120):
    env = dict(os.environ if env is None else env)
    env.pop("ROS_DOMAIN_ID", None)  # as a user starts it: the domain announcement would come first
    return subprocess.run([sys.executable, "-m", "attitude_sil.cli", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout, stdin=subprocess.DEVNULL, env=env)


@pytest.mark.parametrize("args,needle", [
    (("run", "{tmp}/s.yaml"), "plant.duration"),
    (("tune", str(CONFIG / "tune_hst_pid_ga.yaml"), "--set", "seed=abc"), "seed"),
    (("bag", "info", "{tmp}/garbage.mcap"), "not an MCAP file"),
    (("replay", "{tmp}/garbage.mcap", "--rate", "nan"), "--rate"),
    (("run", SCENARIO, "--duration", "x"), "--duration"),
], ids=["run-scenario", "tune-set", "bag-info", "replay", "argparse"])
def test_the_real_process_prints_one_line(tmp_path, args, needle):
    (tmp_path / "s.yaml").write_text(_section("plant", duration=".nan"))
    (tmp_path / "garbage.mcap").write_bytes(GARBAGE)
    proc = _cli(*[a.replace("{tmp}", str(tmp_path)) for a in args])
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert needle in lines[0] and proc.stdout == ""


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["ctrl-c", "sigterm"])
def test_a_stopped_tune_prints_one_line_and_keeps_its_results(tmp_path, sig, code):
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "attitude_sil.cli", "tune", str(CONFIG / "tune_hst_pid_ga.yaml"), "--no-record",
         "--quiet", "--set", f"output={out}", "--set", "algorithm.pop_size=4", "--set", "algorithm.generations=100000",
         "--set", "evaluation.workers=1"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        stdin=subprocess.DEVNULL, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    log = out / "evaluations.jsonl"
    deadline = time.monotonic() + 120
    try:
        while not (log.exists() and log.read_text().count("\n") >= 8):  # two generations are in
            assert proc.poll() is None and time.monotonic() < deadline, (
                proc.communicate() if proc.poll() is not None else "no two generations within 120 s")
            time.sleep(0.05)
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=60)
    finally:  # a tune of 100,000 generations must not outlive a failed test
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines() == [f"{signal.Signals(sig).name}: stopping after this generation "
                                           "(again to stop now)"], stderr
    assert "(interrupted: --resume continues)" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["generations"]) >= 2 and (out / "best.yaml").is_file()
