"""Serve a run live over the Foxglove WebSocket protocol (``foxglove-sdk``): a sink beside the bag writer.

:class:`FoxgloveLive` takes what :class:`~attitude_sil.storage.writer.BagWriter`
takes - a topic with its ROS 2 type, then CDR bytes with a log time - and
serves it to Foxglove clients: one channel per topic with message encoding
``cdr`` and schema encoding ``ros2msg`` holding the same message definition a
bag's schema holds (:func:`~attitude_sil.storage.msgdefs.message_definition`),
so Foxglove decodes the messages exactly as it decodes the bags. The bytes
are the ones received on the wire, served as they are.

One more channel, ``/attitude_sil/status`` (JSON: ``controller_type`` and
``sim_time_s``), is sent every 0.1 s of sim time and at every controller swap,
so a client that connects at any moment sees the active law within 0.1 s of
sim time (``/parameter_events`` only shows a swap when it happens). It is a
Foxglove channel only, not a ROS topic: the graph and the bags are unchanged.

The server counts the channel subscriptions its clients hold, so a run can
hold its first step until somebody watches (:meth:`FoxgloveLive.viewer_ready`,
``run --wait-for-viewer``).

Clients connect through :class:`~attitude_sil.storage.subprotocol.SubprotocolRelay`:
``foxglove-sdk`` accepts only the subprotocol name ``foxglove.sdk.v1``, and
the open-source clients (``@foxglove/ws-protocol``, Lichtblick) ask for
``foxglove.websocket.v1``, the same protocol under its older name.

Nothing here imports rclpy.
"""

from __future__ import annotations

import errno
import json
import socket
import threading
import time

import foxglove
import foxglove.websocket
from foxglove.websocket import Capability, ParameterType, ServerListener, StatusLevel

from attitude_sil.errors import AttitudeSilError

from .msgdefs import message_definition, normalize_type_name
from .subprotocol import SubprotocolRelay

__all__ = ["DEFAULT_PORT", "DEFAULT_HOST", "STATUS_TOPIC", "VIEWER_SETTLE_S", "FoxgloveLive", "check_port"]

#: Foxglove's usual WebSocket port
DEFAULT_PORT = 8765
#: the run is served on this machine only unless the user asks for another address
DEFAULT_HOST = "127.0.0.1"
#: subprotocol names clients ask for -> the one ``foxglove-sdk`` speaks: the same protocol (storage/subprotocol.py)
SUBPROTOCOL_RENAMES = {"foxglove.websocket.v1": "foxglove.sdk.v1"}
#: the status channel (JSON), a Foxglove channel only
STATUS_TOPIC = "/attitude_sil/status"
#: sim time between two status messages, ns
STATUS_PERIOD_NS = 100_000_000
#: how long (s) closing waits for relayed connections to forward what the server sent before it stopped
RELAY_DRAIN_S = 2.0
#: a viewer is ready once it holds a subscription and has added none for this long (s): the subscriptions a client
#: sends together (one per panel's topic) are all in place before the run starts
VIEWER_SETTLE_S = 0.3
#: ... or once this long (s) has passed since its first subscription, whatever it still adds
VIEWER_SETTLE_MAX_S = 3.0

_STATUS_SCHEMA = {
    "type": "object",
    "title": "attitude_sil status",
    "properties": {
        "controller_type": {"type": "string", "description": "the active control law"},
        "sim_time_s": {"type": "number", "description": "simulation time, s"},
    },
}


def check_port(port: int, host: str = DEFAULT_HOST) -> None:
    """Refuse a port out of range or already taken on ``host`` (before any graph starts).

    Raises
    ------
    AttitudeSilError
        The port is not in 1..65535, the host is not an address of this
        machine, or something listens on the port already.
    """
    if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
        raise AttitudeSilError(f"--foxglove port must be an integer in 1..65535, got {port}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise AttitudeSilError(f"--foxglove-host {host!r}: not an address ({exc})") from None
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as a server does: TIME_WAIT is no obstacle
        try:
            sock.bind(address)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise AttitudeSilError(f"--foxglove {port}: port {port} on {host} is in use; choose another port"
                                       ) from None
            raise AttitudeSilError(f"--foxglove {port}: cannot listen on {host}:{port}: "
                                   f"{exc.strerror or exc}") from None


class FoxgloveLive:
    """A Foxglove WebSocket server fed with serialized ROS 2 messages.

    Parameters
    ----------
    port : int
        TCP port (default 8765).
    host : str
        Address to listen on (default ``127.0.0.1``: this machine only).
    name : str
        Server name shown by Foxglove.

    Raises
    ------
    AttitudeSilError
        The port is out of range or in use, or the server cannot start.
    """

    def __init__(self, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST, name: str = "attitude_sil") -> None:
        check_port(port, host)
        self._context = foxglove.Context()
        self.parameters = None  # the graph's parameters (get, set), once the graph is up: see _Parameters
        self._subscribed: set[str] = set()
        # channel subscriptions the clients hold, and when the first and the latest of them came (monotonic s);
        # written by the server's thread, read by the runner's
        self._lock = threading.Lock()
        self._subscriptions = 0
        self._first_subscribe: float | None = None
        self._last_subscribe: float | None = None
        try:  # the SDK's server on this machine only, behind the relay that clients reach
            self._server = foxglove.start_server(name=name, host="127.0.0.1", port=0, context=self._context,
                                                 capabilities=[Capability.Parameters],
                                                 server_listener=_Parameters(self))
        except RuntimeError as exc:
            raise AttitudeSilError(f"--foxglove {port}: {str(exc).splitlines()[0]}") from None
        self._relay = None
        self._requested_port = port
        self.host = host
        self._channels: dict[str, foxglove.Channel] = {}
        self._status = foxglove.Channel(STATUS_TOPIC, schema=_STATUS_SCHEMA, message_encoding="json",
                                        context=self._context)
        self.controller_type = ""
        self._last_status_ns: int | None = None

    def serve(self) -> None:
        """Let clients in (idempotent): once the topics are added, so a client is told of every channel at once.

        A client that connected while channels were still being added lost, now
        and then, a channel's messages altogether (seen with the official
        client, which subscribes to each channel as it is advertised).

        Raises
        ------
        AttitudeSilError
            The address cannot be listened on.
        """
        if self._relay is not None or self._server is None:
            return
        try:
            self._relay = SubprotocolRelay(self.host, self._requested_port, self._server.port, SUBPROTOCOL_RENAMES)
        except OSError as exc:
            raise AttitudeSilError(f"--foxglove {self._requested_port}: cannot listen on {self.host}:"
                                   f"{self._requested_port}: {exc.strerror or exc}") from None

    def viewer_ready(self, now: float | None = None) -> bool:
        """A client subscribes to a channel, and its subscriptions have settled.

        Settled: no subscription added for :data:`VIEWER_SETTLE_S`, or
        :data:`VIEWER_SETTLE_MAX_S` since the first one. ``now``: monotonic
        s (default: the clock now).
        """
        now = time.monotonic() if now is None else now
        with self._lock:
            if self._subscriptions <= 0:
                return False
            return (now - self._last_subscribe >= VIEWER_SETTLE_S
                    or now - self._first_subscribe >= VIEWER_SETTLE_MAX_S)

    def _subscription(self, change: int) -> None:
        """A client subscribed to a channel (+1) or left one (-1)."""
        with self._lock:
            self._subscriptions = max(self._subscriptions + change, 0)
            if change > 0:
                self._last_subscribe = time.monotonic()
                if self._first_subscribe is None:
                    self._first_subscribe = self._last_subscribe

    @property
    def port(self) -> int:
        """The port clients connect to."""
        return self._relay.port if self._relay is not None else self._requested_port

    @property
    def url(self) -> str:
        """``ws://host:port``, what Foxglove's "Open connection" takes."""
        return f"ws://{self.host}:{self.port}"

    def add_topic(self, topic: str, type_name: str) -> None:
        """Advertise ``topic`` (idempotent): message encoding ``cdr``, schema ``ros2msg`` of ``type_name``.

        Raises
        ------
        ValueError
            The type's message definition cannot be found.
        """
        if topic in self._channels:
            return
        full = normalize_type_name(type_name)
        schema = foxglove.Schema(name=full, encoding="ros2msg", data=message_definition(full).encode())
        self._channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding="cdr",
                                                 context=self._context)

    def write(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Send one CDR-serialized message of a topic added before to every subscribed client."""
        channel = self._channels.get(topic)
        if channel is not None and channel.has_sinks():
            channel.log(bytes(data), log_time=int(log_time_ns))

    def set_controller(self, controller_type: str, t_ns: int) -> None:
        """The active law changed (or is known at last): say so on the status channel now."""
        if controller_type != self.controller_type:
            self.controller_type = controller_type
            self._send_status(t_ns)

    def tick(self, t_ns: int) -> None:
        """The sim clock reached ``t_ns``: send the status if 0.1 s of sim time passed (or the clock went back)."""
        last = self._last_status_ns
        if last is None or t_ns < last or t_ns - last >= STATUS_PERIOD_NS:
            self._send_status(t_ns)

    def _send_status(self, t_ns: int) -> None:
        self._last_status_ns = t_ns
        if self.controller_type:
            self._status.log(json.dumps({"controller_type": self.controller_type, "sim_time_s": t_ns * 1e-9}),
                             log_time=int(t_ns))

    def parameters_changed(self, node: str, values: dict) -> None:
        """Parameters of ``node`` (fully qualified) changed (its ``/parameter_events``): tell the clients that
        subscribed to them, under foxglove_bridge's names ``/node.param``."""
        changed = {f"{node}.{k}": v for k, v in values.items() if f"{node}.{k}" in self._subscribed}
        if changed and self._server is not None:
            self._server.publish_parameter_values([_parameter(k, v) for k, v in changed.items()])

    def status(self, text: str, error: bool = True) -> None:
        """A one-line status message to every client (Foxglove shows it in its problems list)."""
        if self._server is not None:
            self._server.publish_status(text, StatusLevel.Error if error else StatusLevel.Info)

    def close(self) -> None:
        """Stop the server (idempotent); clients get what was sent, then see the connection close."""
        if self._server is not None:
            self._server.stop()  # first: the relay forwards what it sent until it closes its side
            self._server = None
            if self._relay is not None:
                self._relay.close(drain_s=RELAY_DRAIN_S)
        if self.parameters is not None:
            self.parameters.close()
            self.parameters = None


def _parameter(name: str, value) -> foxglove.websocket.Parameter:
    """A Foxglove parameter of a plain value; floats typed Float64 (a whole 1.0 is not an integer)."""
    if isinstance(value, float):
        return foxglove.websocket.Parameter(name, value=value, type=ParameterType.Float64)
    if isinstance(value, list) and value and all(isinstance(v, float) for v in value):
        return foxglove.websocket.Parameter(name, value=value, type=ParameterType.Float64Array)
    return foxglove.websocket.Parameter(name, value=value)


class _Parameters(ServerListener):
    """The Parameters capability: get, set and subscribe, through ``live.parameters`` (``get(names) -> dict``,
    ``set(values) -> (dict, errors)``: :class:`attitude_sil.tools.paramclient.GraphParameters`); and the count of
    channel subscriptions (:meth:`FoxgloveLive.viewer_ready`)."""

    def __init__(self, live: FoxgloveLive) -> None:
        self.live = live

    def on_subscribe(self, client, channel) -> None:
        self.live._subscription(+1)

    def on_unsubscribe(self, client, channel) -> None:
        self.live._subscription(-1)

    def on_get_parameters(self, client, param_names, request_id=None):
        source = self.live.parameters
        if source is None:
            return []
        try:
            return [_parameter(k, v) for k, v in source.get(list(param_names)).items()]
        except AttitudeSilError as exc:
            self.live.status(f"parameters: {exc}")
            return []

    def on_set_parameters(self, client, parameters, request_id=None):
        source = self.live.parameters
        if source is None:
            return parameters
        try:
            values, errors = source.set({p.name: p.get_value() for p in parameters})
        except AttitudeSilError as exc:
            values, errors = {}, [f"parameters: {exc}"]
        for line in errors:  # a refused value: the node's own reason, as param set prints it
            self.live.status(line)
        return [_parameter(k, v) for k, v in values.items()]

    def on_parameters_subscribe(self, param_names) -> None:
        self.live._subscribed.update(param_names)

    def on_parameters_unsubscribe(self, param_names) -> None:
        self.live._subscribed.difference_update(param_names)
