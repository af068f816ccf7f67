"""The base of every graph node: parameters from the schema, validation, and ``main()``.

Nodes stay thin: they declare their parameters from
:mod:`attitude_sil.core.sim.params` (through :class:`SchemaNode`), turn messages
into arrays with :mod:`attitude_sil.ros.convert`, call a core step object and
publish the result. :func:`run_node` is the body of every node's ``main()``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
import yaml
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from attitude_sil.core import yaml12
from attitude_sil.core.faults import Fault, added_faults, changes_at, faults_of, foreign_line
from attitude_sil.core.plant.quaternion import unit_or_none
from attitude_sil.core.sim.lockstep import StepInputs, StepSequencer
from attitude_sil.core.sim.paramfile import node_key, sections_for
from attitude_sil.core.sim.params import NODE_PARAMS
from attitude_sil.core.sim.scenario import Scenario, scenario_from_dict
from attitude_sil.errors import AttitudeSilError, ScenarioError
from attitude_sil.ros.contract import DIAGNOSTICS, message_class
from attitude_sil.ros.contract import RECORDED_TOPICS as TOPIC_TYPES
from attitude_sil.ros.convert import fault_diagnostics_msg
from attitude_sil.ros.environment import discovery_profile
from attitude_sil.ros.parameters import PARAMETER_TYPES, descriptor
from attitude_sil.ros.qos import INPUT_QOS, LOCKSTEP_QOS, qos_event_callbacks
from attitude_sil.ros.signals import StopSignals

__all__ = ["SchemaNode", "LockstepNode", "params_file_warning", "run_node", "sim_time_given", "steady_clock"]


#: how long a node waits for its readers' acknowledgement before a tick of a controller on a sim-time timer
#: (:meth:`SchemaNode.await_readers`)
ACK_TIMEOUT = Duration(seconds=1.0)


def steady_clock() -> Clock:
    """A wall clock for watchdogs and pacing (sim time would stall with the graph)."""
    return Clock(clock_type=ClockType.STEADY_TIME)


class SchemaNode(Node):
    """A node whose parameters come from :data:`~attitude_sil.core.sim.params.NODE_PARAMS`.

    Every parameter is declared with a descriptor (type, description, range);
    a set request is validated by the schema rule and then by
    :meth:`check_parameters` (cross-parameter rules); a refusal names the
    parameter and the rule. Accepted values reach :meth:`on_parameters_set`.
    """

    schema_name = ""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.schema_name, **kwargs)
        self.qos_problems: list[str] = []  # subscriptions a publisher cannot match (qos_event_callbacks)
        self._specs = {s.name: s for s in NODE_PARAMS[self.schema_name]}
        for spec in self._specs.values():
            empty = isinstance(spec.default, list) and not spec.default
            default = PARAMETER_TYPES[spec.kind][1] if empty else spec.default
            self.declare_parameter(spec.name, default, descriptor(spec))
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._after_set)
        # validate what came in from overrides or a params file
        for spec in self._specs.values():
            try:
                spec.validate(self.param(spec.name), self.get_name())
            except ValueError as exc:
                raise ScenarioError(f"invalid parameter: {exc}") from None

    # -- parameters ------------------------------------------------------------
    def param(self, name: str) -> Any:
        """Current value of a schema parameter (empty list for an unset array)."""
        if not self.has_parameter(name) or self.get_parameter_or(name).type_ == Parameter.Type.NOT_SET:
            return []
        value = self.get_parameter(name).value
        if value is None and self._specs[name].kind.endswith("_array"):
            return []
        if isinstance(value, (tuple, np.ndarray)) or type(value).__name__ == "array":
            return list(value)
        return value

    def values(self) -> dict[str, Any]:
        """All schema parameters as ``name -> value``."""
        return {name: self.param(name) for name in self._specs}

    def scenario(self) -> Scenario:
        """A scenario holding this node's current parameters (others default)."""
        return scenario_from_dict({self.schema_name: {"ros__parameters": self.values()}},
                                  source=f"node {self.get_name()}", check=False)

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        pending = {}
        for p in params:
            spec = self._specs.get(p.name)
            if spec is None:
                continue  # use_sim_time and friends: rclpy's own rules apply
            value = p.value
            if value is None and spec.kind.endswith("_array"):
                value = []
            try:
                pending[p.name] = spec.validate(list(value) if spec.kind.endswith("_array") else value,
                                                self.get_name())
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        reason = self.check_parameters(pending)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def check_parameters(self, pending: dict[str, Any]) -> str:
        """Cross-parameter rules; return a refusal reason or ''."""
        return ""

    def _after_set(self, params: list[Parameter]) -> None:
        names = [p.name for p in params if p.name in self._specs]
        if names:
            self.on_parameters_set(names)

    def on_parameters_set(self, names: list[str]) -> None:
        """Hook: accepted parameters changed."""

    # -- topics of the contract -----------------------------------------------------
    def step_publisher(self, topic: str):
        """A publisher on a contract topic, with its message type and the lockstep QoS (transient-local)."""
        return self.create_publisher(message_class(TOPIC_TYPES[topic]), topic, LOCKSTEP_QOS,
                                     event_callbacks=qos_event_callbacks(self, topic, LOCKSTEP_QOS, reader=False))

    def step_subscription(self, topic: str, callback: Callable[[Any], None], type_name: str | None = None):
        """A subscription to a contract topic, with its message type (``type_name`` for one the bags do not
        record) and the input QoS (volatile: any reliable publisher matches, a default-QoS one included;
        :mod:`attitude_sil.ros.qos`)."""
        return self.create_subscription(message_class(type_name or TOPIC_TYPES[topic]), topic, callback, INPUT_QOS,
                                        event_callbacks=qos_event_callbacks(self, topic, INPUT_QOS,
                                                                            self.qos_problems))

    # -- helpers ---------------------------------------------------------------
    def await_readers(self, publishers, t_ns: int) -> None:
        """Wait until every reader of ``publishers`` has acknowledged what they published (the step of ``t_ns``,
        ns), up to :data:`ACK_TIMEOUT`; a reader that does not (a stalled or dying one) gets a throttled warning
        and the step goes on."""
        for pub in publishers:
            if not pub.wait_for_all_acked(ACK_TIMEOUT):
                self.get_logger().warning(f"{pub.topic_name}: a reader did not acknowledge the step at "
                                          f"t={t_ns * 1e-9:.6f} s within {ACK_TIMEOUT.nanoseconds * 1e-9:g} s; going "
                                          "on", throttle_duration_sec=1.0)

    @staticmethod
    def finite(array: np.ndarray) -> bool:
        return bool(np.all(np.isfinite(array)))


class LockstepNode(SchemaNode):
    """A node that steps in the lockstep protocol, once per control step stamped t_k (docs/architecture.md).

    What a subclass provides, checked when the class is defined (so a
    missing piece is an error at import, not at step 0):

    * ``schema_name``: its parameters' table in ``NODE_PARAMS`` (with a
      ``control_period``);
    * ``step_inputs``: the contract topics it holds per stamp before it steps
      (:meth:`gather`), ``()`` for a node that steps on one input;
    * ``rebuild()``: (re)build its models from its current parameters; called
      by :meth:`new_episode` at construction and at every new episode (an
      input stamped 0).

    What it gets: ``seq`` (a :class:`~attitude_sil.core.sim.lockstep.StepSequencer`
    of its steps), ``inputs`` (a :class:`~attitude_sil.core.sim.lockstep.StepInputs`
    of ``step_inputs``), ``dt_ns`` (the control period, ns, as of the last
    new episode) and :meth:`gather`.
    """

    step_inputs: tuple[str, ...] | None = None

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        missing = []
        if not cls.schema_name or cls.schema_name not in NODE_PARAMS:
            missing.append("schema_name (a node of NODE_PARAMS)")
        if cls.step_inputs is None:
            missing.append("step_inputs (the topics it gathers per stamp, () for none)")
        if not callable(getattr(cls, "rebuild", None)):
            missing.append("rebuild() (its models from its parameters, at every new episode)")
        if missing:
            raise TypeError(f"lockstep node {cls.__name__} must declare {'; '.join(missing)}")

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.seq = StepSequencer()
        self.inputs = StepInputs(self.step_inputs)
        self.dt_ns = 0

    def refuse_stamp(self, topic: str, t: int, kind: str) -> None:
        """One throttled line for a message of ``topic`` whose stamp ``t`` (ns) the lockstep cannot take
        (``kind``: the :class:`~attitude_sil.core.sim.lockstep.StepSequencer` verdict), naming the stamp it
        expects. A duplicate, a repeat of the step just taken (the plant publishes a step again, e.g. at a
        hold's release), is dropped without a line: it changes nothing."""
        if kind == StepSequencer.DUPLICATE:
            return
        last = self.seq.last_ns
        expected = "0.000000 s (an episode's first step)" if last is None else f"{(last + self.dt_ns) * 1e-9:.6f} s"
        self.get_logger().error(f"{topic} stamped {t * 1e-9:.6f} s refused ({kind}); expected {expected}",
                                throttle_duration_sec=1.0)

    def in_sequence(self, topic: str, t: int, seq: StepSequencer | None = None,
                    on_new: Callable[[], None] | None = None) -> bool:
        """Whether a message of ``topic`` stamped ``t`` (ns) is the next step of ``seq`` (default: the node's):
        a stamp 0 starts an episode first (:meth:`new_episode`, or ``on_new``); a stamp the lockstep cannot
        take is refused (:meth:`refuse_stamp`)."""
        kind = (self.seq if seq is None else seq).classify(t, self.dt_ns)
        if kind == StepSequencer.NEW:
            (self.new_episode if on_new is None else on_new)()
        elif kind != StepSequencer.NEXT:
            self.refuse_stamp(topic, t, kind)
            return False
        return True

    def new_episode(self) -> None:
        """The control period and the subclass's models (``rebuild()``) from the current parameters."""
        self.dt_ns = int(round(self.param("control_period") * 1e9))
        self.rebuild()

    def gather(self, name: str, value: np.ndarray, t: int, inputs: StepInputs | None = None,
               seq: StepSequencer | None = None, on_new: Callable[[], None] | None = None) -> dict | None:
        """One input of a node that steps once it holds all of them for a stamp (the controller, the sensors).

        ``value`` (1, 3) or (1, 4) is checked (finite; a quaternion near unit norm, renormalised) and held
        in ``self.inputs``; once the stamp ``t`` (ns) has every input and comes in sequence (``self.seq``),
        the step's inputs are returned; a new
        episode (stamp 0) calls :meth:`new_episode` first. A refused message is logged and returns None.
        A second stream of steps of the node (the controller's momentum management) passes its own
        ``inputs``, ``seq`` and what a new episode does to it (``on_new``).
        """
        if not self.finite(value):
            self.get_logger().error(f"{name} at t={t * 1e-9:.6f} s is not finite: {value[0].tolist()}; ignored",
                                    throttle_duration_sec=1.0)
            return None
        if value.shape[-1] == 4:
            unit = unit_or_none(value)
            if unit is None:
                self.get_logger().error(f"{name} at t={t * 1e-9:.6f} s is not a unit quaternion (norm "
                                        f"{np.linalg.norm(value):.6g}); ignored", throttle_duration_sec=1.0)
                return None
            value = unit
        inputs, seq = self.inputs if inputs is None else inputs, self.seq if seq is None else seq
        slot = inputs.add(name, t, value)  # the first valid message of a step counts, as in the plant
        if slot is None:
            return None
        if not self.in_sequence(f"{name} (with the step's other inputs)", t, seq, on_new):
            return None
        inputs.taken(t)
        return slot


def params_file_warning(node: Node, args: Sequence[str]) -> str:
    """A warning if ``args`` give ``--params-file`` files and no section of any applies to ``node``.

    rcl silently ignores a section keyed for another node or namespace (a
    plain ``controller:`` does not apply to ``/sat1/controller``), so a node
    would run on its defaults without a word.

    Parameters
    ----------
    node : rclpy.node.Node
        The node, already created (its namespace resolved).
    args : sequence of str
        The command line the node was given (``sys.argv`` for a console script).

    Returns
    -------
    str
        The warning, or ``''`` when no file was given or one has a section for the node.
    """
    files = [args[i + 1] for i, a in enumerate(args[:-1]) if a == "--params-file"]
    if not files:
        return ""
    fqn = node.get_fully_qualified_name()
    keys: list[str] = []
    for name in files:
        try:
            data = yaml12.load(Path(name).read_text())
        except (OSError, yaml.YAMLError):
            return ""  # rcl read the file already; nothing to say about what it could not
        if not isinstance(data, dict):
            continue
        if sections_for(data, fqn):
            return ""
        keys += [str(k) for k in data]
    return (f"no section of the parameter file(s) {', '.join(files)} applies to {fqn} (keys: "
            f"{', '.join(keys) or 'none'}); none of their values is applied. '{node_key(node.get_name())}:' "
            "or '/**:' apply under any namespace")


def sim_time_given(fqn: str, args: Sequence[str]) -> bool:
    """Whether the command line sets ``use_sim_time`` for node ``fqn`` (``-p`` or a ``--params-file`` section).

    A graph node started by hand runs on the plant's ``/clock`` unless the user
    says otherwise: :func:`run_node` turns ``use_sim_time`` on when this is False.

    Parameters
    ----------
    fqn : str
        The node's fully qualified name, e.g. ``/sat1/plant``.
    args : sequence of str
        The command line the node was given.

    Returns
    -------
    bool
    """
    for flag, value in zip(args[:-1], args[1:], strict=True):
        if flag in ("-p", "--param") and value.partition(":=")[0].rsplit(":", 1)[-1] == "use_sim_time":
            return True
        if flag == "--params-file":
            try:
                data = yaml12.load(Path(value).read_text())
            except (OSError, yaml.YAMLError):
                continue
            if isinstance(data, dict) and any(
                    isinstance(section, dict) and "use_sim_time" in (section.get("ros__parameters") or {})
                    for _, section in sections_for(data, fqn)):
                return True
    return False


def run_node(factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """Spin one node in its own process until Ctrl-C, SIGTERM or SIGHUP; the body of every ``main()``.

    Uses rclpy's ``EventsExecutor``: about 7x less overhead per message than the
    default executor on this machine, which is what bounds a lockstep graph.
    The signals set a flag that the spin loop checks between callbacks, so the
    node stops at a clean point (rclpy's own handler would shut the context
    down under a running callback, whose publish then fails with a stack
    trace). Bad parameters print one line and exit 2. ``use_sim_time`` is on
    unless the command line sets it (:func:`sim_time_given`): the plant
    publishes ``/clock``, and ``ros2 run`` of a graph node needs no ``-p
    use_sim_time:=true``.

    Returns
    -------
    int
        0, also after a stop signal (SIGINT, SIGTERM, SIGHUP: a requested shutdown, as ``ros2 launch``
        sends on Ctrl-C, which reports any other code as a died process), 2 for bad parameters.
    """
    discovery_profile()  # before the first participant: found by, and finding, the graph in < 1 s
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopSignals().__enter__()
    node = None
    executor = None
    try:
        node = factory()
        argv = sys.argv if args is None else args
        warning = params_file_warning(node, argv)
        if warning:
            node.get_logger().warning(warning)
        if not sim_time_given(node.get_fully_qualified_name(), argv):
            node.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, True)])
        executor = EventsExecutor()
        executor.add_node(node)
        # spin_once in a loop: EventsExecutor.spin() of rclpy 7.1 leaves service
        # requests unanswered in a separate process
        while rclpy.ok() and not stop.requested:
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (AttitudeSilError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except ParameterException as exc:  # a value outside its descriptor's range or of another type, given at start
        print(f"error: invalid parameter: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        stop.__exit__()
    return 0


class NodeFaults:
    """The faults a node flies (its targets' of its ``faults`` list, :func:`~attitude_sil.core.faults.faults_of`),
    each said on ``/diagnostics`` at the step it becomes active and at the step it ends; lines may be added to
    the list while the graph runs (:meth:`refusal`, :meth:`added`, :meth:`started`)."""

    def __init__(self, node: SchemaNode, name: str) -> None:
        self.node, self.name = node, name
        self.publisher = node.step_publisher(DIAGNOSTICS)
        self.reset()

    def reset(self) -> None:
        """The faults of the node's list as it stands (a new episode)."""
        self.faults = faults_of(self.node.values(), self.name)
        self.lines = list(self.node.param("faults"))  # the list as the episode started or was last added to

    def refusal(self, pending: list[str]) -> str:
        """Why the list ``pending`` cannot replace the node's ('' if it can): a line taken back or changed
        (ScenarioError), or one this node does not fly."""
        return foreign_line(added_faults(self.node.param("faults"), pending), self.name)

    def added(self) -> list[Fault]:
        """The faults of the lines the node's list gained since :meth:`reset` or the last call."""
        new = added_faults(self.lines, self.node.param("faults"))
        self.lines += new
        return faults_of({"faults": new}, self.name)

    def started(self, fault: Fault, step: int, dt_ns: int) -> None:
        """An added ``fault`` flies from ``step`` (steps of ``dt_ns`` ns): said then, at that time."""
        t_s = step * dt_ns * 1e-9
        self.faults.append(replace(fault, time_s=t_s))
        self.node.get_logger().info(f"fault {fault.target} {fault.mode} from t={t_s:g} s")

    def say(self, t_ns: int, dt_ns: int) -> None:
        """``/diagnostics`` for the faults that become active or end at step time ``t_ns`` (ns)."""
        changes = changes_at(self.faults, t_ns // dt_ns, dt_ns)
        if changes:
            self.publisher.publish(fault_diagnostics_msg(changes, t_ns, self.node.get_name()))
