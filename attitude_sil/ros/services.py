"""Client side of the graph's services: get and set another node's parameters, reset the plant.

Both wait by condition (the service is ready, the future is done) while a
caller-supplied ``spin(timeout_s)`` processes callbacks, so they work inside
any executor loop; a node that never answers raises :class:`RunError`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from std_srvs.srv import Trigger

from attitude_sil.errors import RunError

__all__ = ["get_remote_parameters", "set_remote_parameters", "PlantReset", "wait_future", "ask_again"]

Spin = Callable[[float], None]


def wait_future(future, spin: Spin, deadline: float, what: str):
    """Spin until ``future`` is done; raise RunError naming ``what`` after ``deadline`` (monotonic s)."""
    while not future.done():
        if time.monotonic() > deadline:
            raise RunError(f"{what} did not answer")
        spin(0.02)
    return future.result()


def ask_again(send: Callable[[], Any], spin: Spin, deadline: float, what: str, first: float = 1.0):
    """``send()`` (a request's future) until one is answered: again after 1, 2, 4, ... s, up to ``deadline``.

    For idempotent requests (a get). A client's first request can be answered
    before DDS has matched the server's reply writer with the client's
    reader, and that answer is lost: the service looked ready, and waiting
    longer would not help.
    """
    wait = first
    while True:
        try:
            return wait_future(send(), spin, min(deadline, time.monotonic() + wait), what)
        except RunError:
            if time.monotonic() > deadline:
                raise
            wait *= 2.0


def get_remote_parameters(node: Node, spin: Spin, target: str, names: list[str],
                          timeout: float = 10.0) -> dict[str, Any]:
    """Values of parameters ``names`` of node ``target``, through its parameter service.

    Returns
    -------
    dict
        ``name -> value`` (arrays as lists) for each name the node has set;
        a name it does not have is left out.

    Raises
    ------
    RunError
        The service did not appear or answer within ``timeout`` s.
    """
    client, deadline = _parameter_client(node, spin, target, timeout)
    what = f"{target} (parameter get)"
    values = ask_again(lambda: client.get_parameters(names), spin, deadline, what).values
    if len(values) != len(names):
        # rclpy answers nothing for a batch holding a name declared with a type but no value (an
        # empty array here) or not declared: ask name by name (one at a time: a service keeps
        # only its last 10 requests)
        answers = [ask_again(lambda n=name: client.get_parameters([n]), spin, deadline, what).values
                   for name in names]
        pairs = [(name, a[0]) for name, a in zip(names, answers, strict=True) if a]
    else:
        pairs = list(zip(names, values, strict=True))
    out: dict[str, Any] = {}
    for name, value in pairs:
        v = parameter_value_to_python(value)
        if v is not None:  # None: not set
            out[name] = v
    return out


def _parameter_client(node: Node, spin: Spin, target: str, timeout: float) -> tuple[AsyncParameterClient, float]:
    """A parameter client of ``target`` once its services are there, and the deadline of the whole call."""
    client = AsyncParameterClient(node, target)
    deadline = time.monotonic() + timeout
    while not client.services_are_ready():
        if time.monotonic() > deadline:
            raise RunError(f"parameter service of {target} did not appear within {timeout:g} s")
        spin(0.02)
    return client, deadline


def set_remote_parameters(node: Node, spin: Spin, target: str, params: dict[str, Any],
                          timeout: float = 10.0) -> None:
    """Set parameters of node ``target`` through its parameter service.

    Raises
    ------
    RunError
        The service did not appear or answer within ``timeout`` s, or ``target``
        refused a value (the message names the parameter and the node's reason).
    """
    client, deadline = _parameter_client(node, spin, target, timeout)
    result = wait_future(client.set_parameters([Parameter(k, value=v) for k, v in params.items()]), spin, deadline,
                         f"{target} (parameter set)")
    for name, r in zip(params, result.results, strict=True):
        if not r.successful:
            raise RunError(f"{target} refused {name}: {r.reason}")


class PlantReset:
    """The plant's ``reset`` service (std_srvs/Trigger): one client for every reset of a session.

    Make it with the caller's node, before waiting for the graph. A client's
    first request can be answered before DDS has matched the server's reply
    writer with the client's new reader (rmw_fastrtps waits 100 ms for that
    match, then drops the answer): a client made just before its call lost a
    reset's answer on a loaded machine while the plant ran the episode. A
    reset cannot be asked again as a get can (:func:`ask_again`); a client
    made early has been matched long before its first call. (A plant that
    restarts mid-session opens the window again: its new server has not
    matched the reader yet.)

    Parameters
    ----------
    node : Node
        The node that calls.
    service : str
        The service's name (the plant's, under the graph's namespace).
    """

    def __init__(self, node: Node, service: str = "plant/reset") -> None:
        self.service = service
        self.client = node.create_client(Trigger, service)

    def __call__(self, spin: Spin, timeout: float) -> str:
        """Reset the plant (an episode starts); returns its message.

        Raises
        ------
        RunError
            The service did not appear or answer within ``timeout`` s, or the
            plant refused the reset.
        """
        deadline = time.monotonic() + timeout
        while not self.client.service_is_ready():
            if time.monotonic() > deadline:
                raise RunError(f"service {self.service} did not appear")
            spin(0.02)
        response = wait_future(self.client.call_async(Trigger.Request()), spin, deadline, self.service)
        if not response.success:
            raise RunError(response.message)
        return response.message
