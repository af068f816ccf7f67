"""``attitude-sil param``: list, get, set, dump and load parameters of a running node.

The project's stand-in for ``ros2 param`` (ros2cli is not on PyPI), built on
rclpy's ``AsyncParameterClient``, printing what ``ros2 param`` prints:
``list`` one indented name a line, ``get`` ``Double value is: 1.0`` (arrays as
``Double values are: [1.0, 2.0]``, a list where ros2 prints the Python
``array``), ``set`` ``Set parameter successful``, ``dump`` the node's
parameters as a ``/node: ros__parameters:`` file, ``load`` one ``Set
parameter X successful`` / ``Set parameter X failed: reason`` line per
parameter. Values given on the command line or in a file are parsed as YAML
(1.2 numbers) and converted to the parameter's declared type (so ``[1, 2,
3]`` sets a double array). A refusal prints the node's reason and exits
non-zero.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rclpy
import yaml
from rcl_interfaces.msg import ParameterType as T
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient

from attitude_sil.core import yaml12
from attitude_sil.core.sim.paramfile import sections_for
from attitude_sil.core.sim.scenario import flatten_parameters
from attitude_sil.errors import ParamClientError, RunError
from attitude_sil.ros.contract import check_node_name, check_parameter_name
from attitude_sil.ros.environment import localhost_environment
from attitude_sil.ros.services import ask_again, wait_future

__all__ = ["GraphParameters", "LoadReport", "ParamClientError", "file_values", "format_dump", "param_command",
           "param_dump", "param_load"]

#: ``ros2 param get``'s label of each value type
_LABELS = {
    T.PARAMETER_BOOL: "Boolean value is:", T.PARAMETER_INTEGER: "Integer value is:",
    T.PARAMETER_DOUBLE: "Double value is:", T.PARAMETER_STRING: "String value is:",
    T.PARAMETER_BYTE_ARRAY: "Byte values are:", T.PARAMETER_BOOL_ARRAY: "Boolean values are:",
    T.PARAMETER_INTEGER_ARRAY: "Integer values are:", T.PARAMETER_DOUBLE_ARRAY: "Double values are:",
    T.PARAMETER_STRING_ARRAY: "String values are:",
}


def _coerce(value: Any, ptype) -> Any:
    """YAML value -> the declared parameter type (ints become floats for doubles)."""
    def num(v, kind):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ParamClientError(f"expected a number, got {v!r}")
        return float(v) if kind == "double" else v

    if ptype == T.PARAMETER_DOUBLE:
        return num(value, "double")
    if ptype == T.PARAMETER_DOUBLE_ARRAY:
        if not isinstance(value, list):
            raise ParamClientError(f"expected a list of numbers, got {value!r}")
        return [num(v, "double") for v in value]
    if ptype == T.PARAMETER_INTEGER_ARRAY:
        if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise ParamClientError(f"expected a list of integers, got {value!r}")
        return value
    if ptype == T.PARAMETER_STRING and not isinstance(value, str):
        return str(value)
    return value


def _plain(value: Any) -> Any:
    """A parameter value as plain Python (lists, not ``array``s or tuples)."""
    if isinstance(value, (list, tuple)) or type(value).__name__ in ("array", "ndarray"):
        return list(value)
    return value


def _format(value: Any) -> str:
    value = _plain(value)
    if isinstance(value, list):
        return "[" + ", ".join(str(v) for v in value) + "]"
    return str(value)


def _fqn(node_name: str) -> str:
    return "/" + node_name.strip("/")


class _Session:
    """A private rclpy context, node and parameter client of one remote node."""

    def __init__(self, node_name: str, timeout: float) -> None:
        self.node_name = node_name
        self.timeout = timeout
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context)
        self.node = rclpy.create_node(f"attitude_sil_param_{int(time.time() * 1000) % 100000}",
                                      context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.client = AsyncParameterClient(self.node, node_name)

    def connect(self) -> None:
        deadline = time.monotonic() + self.timeout
        while not self.client.services_are_ready():
            if time.monotonic() > deadline:
                raise ParamClientError(f"node {self.node_name} not found within {self.timeout:g} s "
                                       "(is the graph running, on this ROS_DOMAIN_ID?)")
            self.executor.spin_once(timeout_sec=0.05)

    def _answer(self, waiting):
        """``waiting(spin, deadline, what)`` (a ros.services wait) within the timeout, as a ParamClientError."""
        try:
            return waiting(lambda t: self.executor.spin_once(timeout_sec=t), time.monotonic() + self.timeout,
                           f"node {self.node_name}")
        except RunError:
            raise ParamClientError(f"node {self.node_name} did not answer within {self.timeout:g} s") from None

    def wait(self, future):
        """The answer to a request sent once (a set: sent again, it would be applied twice)."""
        return self._answer(lambda spin, deadline, what: wait_future(future, spin, deadline, what))

    def ask(self, send):
        """The answer to a read (get, describe, list), sent again after 1, 2, 4 s while none comes
        (:func:`attitude_sil.ros.services.ask_again`: a first answer can be lost while DDS matches the client)."""
        return self._answer(lambda spin, deadline, what: ask_again(send, spin, deadline, what))

    def _each(self, ask, field: str, names: list[str]) -> dict[str, Any]:
        # rclpy's parameter services answer nothing at all for a batch when one name is not
        # declared (describe) or declared with a type but no value (get: an empty array
        # parameter here); such a batch is asked again name by name, None where nothing comes
        got = getattr(self.ask(lambda: ask(names)), field)
        if len(got) == len(names):
            return dict(zip(names, got, strict=True))
        out = {}
        for name in names:
            one = getattr(self.ask(lambda n=name: ask([n])), field)
            out[name] = one[0] if one else None
        return out

    def names(self) -> list[str]:
        """Every parameter the node has, sorted."""
        return sorted(self.ask(self.client.list_parameters).result.names)

    def values(self, names: list[str]) -> dict[str, Any]:
        """``name -> ParameterValue``, ``None`` for one not declared or declared without a value."""
        return self._each(self.client.get_parameters, "values", names)

    def descriptors(self, names: list[str]) -> dict[str, Any]:
        """``name -> ParameterDescriptor``, ``None`` (or type NOT_SET) for one not declared."""
        return self._each(self.client.describe_parameters, "descriptors", names)

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@contextmanager
def remote_session(node_name: str, timeout: float) -> Iterator[_Session]:
    """A private rclpy context with a parameter client of ``node_name``, connected (ParamClientError: not within
    ``timeout`` s)."""
    if not (isinstance(timeout, (int, float)) and math.isfinite(timeout) and timeout > 0):
        raise ParamClientError(f"--timeout must be a finite number of seconds > 0, got {timeout}")
    check_node_name(node_name)
    localhost_environment()
    session = _Session(node_name, timeout)
    try:
        session.connect()
        yield session
    finally:
        session.close()


def param_command(action: str, node_name: str, name: str | None = None, value: str | None = None,
                  timeout: float = 10.0, hide_type: bool = False) -> str:
    """Run one ``list``, ``get`` or ``set`` against ``node_name``; return the text to print.

    Parameters
    ----------
    action : {"list", "get", "set"}
    node_name : str
        ``controller``, ``/controller`` or ``/sat1/controller``.
    name : str, optional
        The parameter (``get``, ``set``).
    value : str, optional
        The new value as YAML (``set``).
    timeout : float
        Seconds to wait for the node and for each answer.
    hide_type : bool
        ``get`` prints the value only (``ros2 param get --hide-type``).

    Raises
    ------
    ParamClientError
        Node not found, unknown parameter, bad value or refusal.
    """
    if name is not None:
        check_parameter_name(name)
    with remote_session(node_name, timeout) as s:
        if action == "list":
            names = s.names()
            return "\n".join(f"  {n}" for n in names)
        assert name is not None
        desc = s.descriptors([name])[name]
        if desc is None or desc.type == T.PARAMETER_NOT_SET:
            raise ParamClientError(f"node {node_name} has no parameter {name!r}")
        if action == "get":
            pvalue = s.values([name])[name]
            if pvalue is None or pvalue.type == T.PARAMETER_NOT_SET:
                return "Parameter not set."
            text = _format(parameter_value_to_python(pvalue))
            return text if hide_type else f"{_LABELS.get(pvalue.type, 'Value is:')} {text}"
        if action == "set":
            try:
                parsed = yaml12.load(value) if value is not None else None
            except yaml.YAMLError:
                raise ParamClientError(f"value {value!r} is not valid YAML") from None
            try:
                typed = _coerce(parsed, desc.type)
            except ParamClientError as exc:
                raise ParamClientError(f"{node_name}.{name}: {exc}") from None
            result = s.wait(s.client.set_parameters([Parameter(name, value=typed)])).results[0]
            if not result.successful:
                raise ParamClientError(f"Setting parameter failed: {result.reason}")
            return "Set parameter successful" + (f": {result.reason}" if result.reason else "")
        raise ParamClientError(f"unknown action {action!r}")


def format_dump(fqn: str, values: dict[str, Any]) -> str:
    """``{name: value}`` as ``ros2 param dump`` writes it: ``/node: ros__parameters:``, nested at the dots.

    Parameters
    ----------
    fqn : str
        The node's fully qualified name, the file's one key.
    values : dict
        Parameter name -> plain value.

    Returns
    -------
    str
        YAML text (leaf lists in flow style).
    """
    tree: dict[str, Any] = {}
    for name in sorted(values):
        *parents, leaf = name.split(".")
        level = tree
        for p in parents:
            level = level.setdefault(p, {})
        level[leaf] = _plain(values[name])
    return yaml.safe_dump({fqn: {"ros__parameters": tree}}, default_flow_style=None, sort_keys=True)


def param_dump(node_name: str, timeout: float = 10.0) -> str:
    """Every parameter of a running node as a ROS 2 parameter file (``ros2 param dump``).

    Raises
    ------
    ParamClientError
        Node not found or not answering.
    """
    with remote_session(node_name, timeout) as s:
        names = s.names()
        pvalues = s.values(names)
    # a parameter declared without a value has nothing to write (ros2 param dump cannot either)
    return format_dump(_fqn(node_name), {n: parameter_value_to_python(v) for n, v in pvalues.items()
                                         if v is not None and v.type != T.PARAMETER_NOT_SET})


@dataclass
class LoadReport:
    """What ``param load`` did, parameter by parameter.

    Attributes
    ----------
    lines : list of (str, bool)
        ``("Set parameter X successful", True)`` / ``("Set parameter X failed: reason", False)``, in file order.
    unchanged : list of str
        Parameters already at the file's value: not sent (a read-only one would be refused for nothing).
    """

    lines: list[tuple[str, bool]] = field(default_factory=list)
    unchanged: list[str] = field(default_factory=list)

    @property
    def failed(self) -> bool:
        """Whether any parameter was refused."""
        return not all(ok for _, ok in self.lines)


def file_values(path: str | Path, fqn: str) -> dict[str, Any]:
    """The parameters a ROS 2 parameter file gives node ``fqn``: every section that applies, in file order.

    Raises
    ------
    ParamClientError
        Missing or malformed file, or no section for the node.
    """
    p = Path(path)
    try:
        data = yaml12.load(p.read_text())
    except OSError as exc:
        raise ParamClientError(f"{p}: {exc.strerror or exc}") from None
    except yaml.YAMLError:
        raise ParamClientError(f"{p}: not valid YAML") from None
    if not isinstance(data, dict):
        raise ParamClientError(f"{p}: a parameter file maps node names to ros__parameters")
    values: dict[str, Any] = {}
    sections = sections_for(data, fqn)
    if not sections:
        raise ParamClientError(f"{p}: no section applies to {fqn} (keys: {', '.join(map(str, data)) or 'none'})")
    for key, section in sections:
        params = section.get("ros__parameters") if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise ParamClientError(f"{p}: {key}: expected 'ros__parameters:' with a mapping of values")
        values.update(flatten_parameters(params))
    return values


def param_load(node_name: str, path: str | Path, timeout: float = 10.0) -> LoadReport:
    """Set a running node's parameters from a ROS 2 parameter file (``ros2 param load``).

    Every section that applies to the node counts (``/**``, ``/**/node``,
    ``/node``, ...), so a tuner's ``best.yaml`` loads into ``/controller``.
    Parameters already at the file's value are not sent; the others go in one
    request, each accepted or refused on its own (not atomically), in file
    order.

    Raises
    ------
    ParamClientError
        Bad file, no section for the node, node not found or not answering.
    """
    values = file_values(path, _fqn(node_name))
    report = LoadReport()
    with remote_session(node_name, timeout) as s:
        names = list(values)
        descs = s.descriptors(names)
        current = s.values(names)
        to_send: list[Parameter] = []
        verdict: dict[str, tuple[str, bool] | None] = {}
        for name in names:
            desc, cur = descs[name], current[name]
            if desc is None or desc.type == T.PARAMETER_NOT_SET:
                verdict[name] = (f"Set parameter {name} failed: {node_name} has no parameter {name!r}", False)
                continue
            try:
                typed = _coerce(values[name], desc.type)
            except ParamClientError as exc:
                verdict[name] = (f"Set parameter {name} failed: {exc}", False)
                continue
            if cur is not None and cur.type != T.PARAMETER_NOT_SET and _plain(parameter_value_to_python(cur)) == typed:
                report.unchanged.append(name)
                continue
            verdict[name] = None
            to_send.append(Parameter(name, value=typed))
        if to_send:
            results = s.wait(s.client.set_parameters(to_send)).results
            for param, result in zip(to_send, results, strict=True):
                state = "successful" if result.successful else "failed"
                verdict[param.name] = (f"Set parameter {param.name} {state}"
                                       + (f": {result.reason}" if result.reason else ""), result.successful)
    report.lines = [v for v in verdict.values() if v is not None]
    return report


class GraphParameters:
    """The parameters of a running graph's nodes, under foxglove_bridge's names ``/ns/node.param``.

    What the live view's Parameters capability reads and sets
    (:class:`attitude_sil.storage.foxglove.FoxgloveLive`): a set goes
    through the node's parameter service as ``param set`` does (the value
    converted to the declared type; a refusal comes back with the node's
    reason), so a ``controller_type`` set from Foxglove swaps the law as
    ``param set`` does and shows in ``/parameter_events``. One private rclpy
    context per node (:class:`_Session`), opened on first use; calls from
    several threads (the server's) take turns.

    Parameters
    ----------
    namespace : str, optional
        The graph's namespace.
    nodes : sequence of str
        The graph's node names.
    timeout : float
        Seconds to wait for a node and for each answer. A client connects as
        soon as the server is up, while the graph is still starting, and its
        first get waits for the node: the default is the time the graph's own
        discovery may take (``GraphSession``'s ``connect_timeout``); reads are
        sent again while no answer comes.
    """

    def __init__(self, namespace: str | None = None, nodes=(), timeout: float = 20.0) -> None:
        localhost_environment()
        self.fqns = {_fqn(f"{namespace}/{n}" if namespace else n) for n in nodes}
        self.timeout = timeout
        self._sessions: dict[str, _Session] = {}
        self._lock = threading.Lock()

    def _session(self, fqn: str) -> _Session:
        session = self._sessions.get(fqn)
        if session is None:
            session = _Session(fqn, self.timeout)
            session.connect()
            self._sessions[fqn] = session
        return session

    def _by_node(self, names) -> dict[str, list[str]]:
        out: dict[str, list[str]] = {}
        for full in names:
            fqn, _, name = full.partition(".")
            out.setdefault(fqn, []).append(name)
        return out

    def get(self, names: list[str]) -> dict[str, Any]:
        """``{"/node.param": value}`` of ``names``, or of every parameter of every node when empty.

        A name of another node, or one a node does not hold, is left out.
        """
        with self._lock:
            wanted = self._by_node(names) if names else {fqn: [] for fqn in sorted(self.fqns)}
            out: dict[str, Any] = {}
            for fqn, params in wanted.items():
                if fqn not in self.fqns:
                    continue
                session = self._session(fqn)
                params = params or session.names()
                for name, pvalue in session.values(params).items():
                    if pvalue is not None and pvalue.type != T.PARAMETER_NOT_SET:
                        out[f"{fqn}.{name}"] = _plain(parameter_value_to_python(pvalue))
            return out

    def set(self, values: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
        """Set ``{"/node.param": value}``; returns the values after it and one line per refusal."""
        errors: list[str] = []
        with self._lock:
            for fqn, names in self._by_node(values).items():
                if fqn not in self.fqns:
                    errors.append(f"{fqn}: not a node of this graph ({', '.join(sorted(self.fqns))})")
                    continue
                session = self._session(fqn)
                descriptors = session.descriptors(names)
                typed = []
                for name in names:
                    desc = descriptors.get(name)
                    if desc is None or desc.type == T.PARAMETER_NOT_SET:
                        errors.append(f"node {fqn} has no parameter {name!r}")
                        continue
                    try:
                        typed.append(Parameter(name, value=_coerce(values[f"{fqn}.{name}"], desc.type)))
                    except ParamClientError as exc:
                        errors.append(f"{fqn}.{name}: {exc}")
                results = session.wait(session.client.set_parameters(typed)).results if typed else []
                errors += [f"Setting parameter failed: {r.reason}" for r in results if not r.successful]
        return self.get(list(values)), errors

    def close(self) -> None:
        """Close every session (idempotent)."""
        with self._lock:
            for session in self._sessions.values():
                session.close()
            self._sessions.clear()
