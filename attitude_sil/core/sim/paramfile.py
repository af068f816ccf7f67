"""Section keys of ROS 2 parameter files, and which node a key applies to.

A ROS 2 parameter file maps node keys to ``ros__parameters``. rcl gives a key
without a leading ``/`` one, and matches it against a node's fully qualified
name with two wildcards: ``*`` is one namespace token, ``**`` any number
(none included). So ``controller:`` means ``/controller`` only, while
``/**/controller:`` applies to a node named ``controller`` under any
namespace, which is why every file the project writes uses that form
(:func:`node_key`). Nothing here imports rclpy.
"""

from __future__ import annotations

import re
from typing import Any

from attitude_sil.core.sim.params import GLOBAL_NODE

__all__ = ["applies_to", "node_key", "section_node", "sections_for"]


def node_key(node: str) -> str:
    """The section key a written file uses for ``node``: ``/**/<node>`` (any namespace).

    Parameters
    ----------
    node : str
        Plain node name, e.g. ``controller``.

    Returns
    -------
    str
        E.g. ``/**/controller``.
    """
    return f"{GLOBAL_NODE}/{node}"


def _tokens(key: str) -> list[str]:
    return [t for t in str(key).strip().strip("/").split("/") if t]


def applies_to(key: str, fqn: str) -> bool:
    """Whether section ``key`` of a parameter file applies to the node ``fqn``, as rcl matches it.

    Parameters
    ----------
    key : str
        A section key: ``/**``, ``/**/controller``, ``controller``, ``/sat1/controller``, ``/*/controller``.
    fqn : str
        The node's fully qualified name, e.g. ``/sat1/controller``.

    Returns
    -------
    bool
    """
    pattern = ""
    for token in _tokens(key):
        if token == "**":
            pattern += r"(?:/[^/]+)*"
        elif token == "*":
            pattern += r"/[^/]+"
        else:
            pattern += "/" + re.escape(token)
    return bool(pattern) and re.fullmatch(pattern, "/" + fqn.strip("/")) is not None


def section_node(key: str) -> str:
    """The node a section key names, its namespace part ignored (one graph's view).

    ``/**/controller``, ``controller``, ``/controller`` and ``/sat1/controller``
    all name ``controller``; ``/**`` (and a key ending in a wildcard, such as
    ``/*``) names every node: :data:`~attitude_sil.core.sim.params.GLOBAL_NODE`.

    Parameters
    ----------
    key : str
        A section key of a parameter file.

    Returns
    -------
    str
        The plain node name, or ``/**``.
    """
    tokens = _tokens(key)
    if not tokens or tokens[-1] in ("*", "**"):
        return GLOBAL_NODE
    return tokens[-1]


def sections_for(data: dict[Any, Any], fqn: str) -> list[tuple[str, Any]]:
    """The ``(key, section)`` pairs of a parameter mapping that apply to node ``fqn``, in file order.

    Parameters
    ----------
    data : dict
        A parsed parameter file (keys -> ``{"ros__parameters": ...}``).
    fqn : str
        The node's fully qualified name.

    Returns
    -------
    list of (str, object)
        Sections that apply; later ones override earlier ones.
    """
    return [(str(k), v) for k, v in data.items() if applies_to(str(k), fqn)]
