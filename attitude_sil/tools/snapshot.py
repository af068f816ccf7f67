"""A bag's recorded controller parameters, read where other laws may be installed than when it was recorded.

A run keeps the controller's full parameter set in its bag: the snapshot in
``metadata.yaml`` holds ``<law>.<param>`` of every law installed at the time,
plugins included, and the recorded ``/parameter_events`` may set them too.
A bag must outlive that environment, so what reads it back
(``replay --verify-controller``) sorts them here:

* the parameters of a law that is not installed now are left out, and the
  caller gives one notice naming those laws (:func:`drop_uninstalled`,
  :func:`notice`);
* a law that flew (the snapshot's ``controller_type``, or a recorded swap)
  must be installed: it is what is being verified, so a bag that flew one
  that is not is refused in one line naming it (:func:`check_installed`).

Nothing here imports rclpy.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from attitude_sil.core.control import registry
from attitude_sil.core.sim.params import NODE_PARAMS
from attitude_sil.errors import BagError

__all__ = ["uninstalled_law", "drop_uninstalled", "check_installed", "notice"]


def uninstalled_law(name: str) -> str | None:
    """The law a controller parameter belongs to when that law is not installed, else None.

    ``my_law.kd`` gives ``my_law`` where no installed law is called
    ``my_law``. A name the controller declares, or whose prefix is one of
    its groups (``pid.kq``, ``orbit.x``: a misspelling, not a missing law),
    or that has no prefix, gives None: the schema judges those.
    """
    head, dot, _ = str(name).partition(".")
    if not dot or not head:
        return None
    declared = {s.name for s in NODE_PARAMS["controller"]}
    groups = {n.partition(".")[0] for n in declared if "." in n}
    if name in declared or head in groups or head in registry.names():
        return None
    return head


def drop_uninstalled(params: Mapping[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """``params`` (controller parameter name -> value) without the parameters of laws not installed, and those
    laws' names (sorted, each once)."""
    kept: dict[str, Any] = {}
    laws: set[str] = set()
    for name, value in params.items():
        law = uninstalled_law(name)
        if law is None:
            kept[name] = value
        else:
            laws.add(law)
    return kept, sorted(laws)


def _installed_list() -> str:
    return ", ".join(registry.names())


def check_installed(law: Any, where: str, when: str = "") -> None:
    """Refuse, in one line, a bag whose flown ``controller_type`` ``law`` is not installed.

    Parameters
    ----------
    law : object
        The recorded ``controller_type`` value (a value that is not a string
        is left to the schema to refuse).
    where : str
        The bag, for the message.
    when : str
        Where in the bag it flew, e.g. ``" (swapped to at t=5.000 s)"``.

    Raises
    ------
    BagError
        ``law`` is a string naming no installed law.
    """
    if not isinstance(law, str) or law in registry.names():
        return
    if law in registry.declared_names():  # an entry point that did not load: the registry said why on stderr
        state, todo = "whose plugin did not load", "the line above says why"
    else:
        state, todo = "which is not installed", "install it to verify this bag"
    raise BagError(f"{where}: the bag flew controller_type {law}{when}, {state} (installed: {_installed_list()}); "
                   f"{todo}")


def notice(where: str, laws: Iterable[str]) -> str:
    """The one line that says a bag's parameters of ``laws`` (not installed, not flown) were left out."""
    laws = list(laws)
    if len(laws) == 1:
        what, them = f"{laws[0]}, a law", "it"
    else:
        what, them = f"{', '.join(laws[:-1])} and {laws[-1]}, laws", "them"
    return f"note: {where}: ignoring the recorded parameters of {what} not installed here (the bag did not fly {them})"
