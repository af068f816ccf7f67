"""What a 3D view draws of the spacecraft: its frames and a body model, from a scenario's parameter values.

Frames, by their names in the topic contract: ``inertial`` (N), ``body`` (B)
and, where the scenario flies an orbit, ``lvlh`` (L). A transform from a
parent frame to a child frame carries the child's orientation relative to
the parent, the convention of ``tf2``: ``inertial -> body`` is the attitude
``q_BN`` itself, ``inertial -> lvlh`` is ``q_LN(t)`` (:func:`lvlh_attitude`),
the frame the guidance's ``lvlh`` mode tracks and the orbit disturbances use.
All frames share the body's centre of mass as their origin (the simulation
has attitude, not position), so every translation is zero.

The body model, drawn in ``body`` (markers with the codes of
``visualization_msgs/Marker``):

* the body: a box with the proportions of a uniform box of the body's
  principal moments (the diagonal of ``plant.inertia``), its longest edge
  :data:`BODY_SIZE_M` (the model has no mass or size, only inertia);
* each reaction wheel (``wheels.geometry``; the speed-loop wheels of
  ``wheels.actuator: speed_loop`` lie on the body axes): its spin axis as an
  arrow out of the centre, a disc across the axis, and its joint name at the
  tip; torque rods (``wheels.actuator: torque``) have no wheels to draw.

Quaternions are ROS order ``(x, y, z, w)``, Hamilton.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from attitude_sil.core.plant.disturbance import lvlh_attitude, orbit_rate
from attitude_sil.core.plant.quaternion import quat_from_euler
from attitude_sil.core.plant.wheels import GEOMETRIES, orthogonal_triad

__all__ = ["INERTIAL", "BODY", "LVLH", "BODY_SIZE_M", "ARROW", "CUBE", "CYLINDER", "TEXT", "SceneMarker",
           "BodyScene", "body_scene", "box_from_inertia", "rotation_z_to"]

#: frame names (contract)
INERTIAL, BODY, LVLH = "inertial", "body", "lvlh"
#: the body box's longest edge, m (display size)
BODY_SIZE_M = 1.0
#: ``visualization_msgs/Marker`` type codes used here
ARROW, CUBE, CYLINDER, TEXT = 0, 1, 3, 9
#: disturbance models that fly the orbit frame
_ORBIT_MODELS = ("gravity_gradient", "aerodynamic")
#: one colour per wheel (r, g, b, a), repeated past the fourth
_WHEEL_COLOURS = ((0.90, 0.30, 0.25, 1.0), (0.25, 0.70, 0.30, 1.0), (0.25, 0.45, 0.90, 1.0),
                  (0.95, 0.75, 0.20, 1.0))


@dataclass(frozen=True)
class SceneMarker:
    """One marker of the body model, in the ``body`` frame.

    ``position`` (3,) m, ``orientation`` (4,) x y z w, ``scale`` (3,) m (an
    arrow given by ``points``: shaft diameter, head diameter, head length),
    ``color`` (4,) r g b a in 0..1, ``points`` (m, 3) m, ``type`` a
    ``visualization_msgs/Marker`` code.
    """

    ns: str
    id: int
    type: int
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    points: tuple[tuple[float, float, float], ...] = ()
    text: str = ""


@dataclass(frozen=True)
class BodyScene:
    """The frames and the body model of one scenario.

    Attributes
    ----------
    markers : tuple of SceneMarker
        The body model, in ``body``.
    q_LN0 : ndarray, shape (4,), or None
        The LVLH frame at t = 0 relative to N; None without an orbit.
    orbit_rate : float
        LVLH's rate about its y axis, rad/s (0 without an orbit).
    orbit : object, optional
        A propagated orbit (``at(t_ns).q_LN``, ``core.environment.ephemeris.Ephemeris``): LVLH is its frame,
        not the circular one of ``q_LN0`` and ``orbit_rate``.
    """

    markers: tuple[SceneMarker, ...]
    q_LN0: np.ndarray | None = None
    orbit_rate: float = 0.0
    orbit: Any = None
    frames: tuple[tuple[str, str], ...] = field(init=False)

    def __post_init__(self) -> None:
        pairs = ((INERTIAL, BODY),) + (((INERTIAL, LVLH),) if self.q_LN0 is not None else ())
        object.__setattr__(self, "frames", pairs)

    def rotations(self, t: float, q_BN) -> list:
        """Each transform's rotation at sim time ``t`` (s) for attitude ``q_BN`` (4,): in :attr:`frames` order."""
        if self.q_LN0 is None:
            return [q_BN]
        return [q_BN, self._lvlh(t)]

    def _lvlh(self, t: float) -> np.ndarray:
        """LVLH at sim time ``t`` (s): the propagated orbit's, or the circular one's."""
        if self.orbit is not None:
            return self.orbit.at(int(round(t * 1e9))).q_LN
        return lvlh_attitude(t, self.q_LN0, self.orbit_rate)

    def rotation_series(self, t: np.ndarray, q_BN: np.ndarray) -> list[np.ndarray]:
        """:meth:`rotations` over a series: ``t`` (n,) s, ``q_BN`` (n, 4); one (n, 4) array per transform."""
        q_BN = np.asarray(q_BN, dtype=float)
        if self.q_LN0 is None:
            return [q_BN]
        return [q_BN, np.array([self._lvlh(float(tk)) for tk in t])]


def box_from_inertia(inertia, longest: float = BODY_SIZE_M) -> np.ndarray:
    """Edges (3,) m of a uniform box with the principal moments ``inertia``, scaled so its longest edge is ``longest``.

    A uniform box of mass m and edges a, b, c has ``I_x = m (b^2 + c^2) / 12``
    and its cyclic shifts, so ``a^2 = 6 (I_y + I_z - I_x) / m``. A 3 x 3
    inertia contributes its diagonal. An edge is kept at least a tenth of the
    longest (a flat body still shows as a slab).

    Parameters
    ----------
    inertia : array_like, shape (3,) or (3, 3) or (9,)
        kg m^2.
    longest : float
        The longest edge, m.
    """
    values = np.asarray(inertia, dtype=float).ravel()
    diag = values if values.size == 3 else values.reshape(3, 3).diagonal()
    squares = np.array([diag[1] + diag[2] - diag[0], diag[2] + diag[0] - diag[1], diag[0] + diag[1] - diag[2]])
    edges = np.sqrt(np.clip(squares, 0.0, None))
    if not np.all(np.isfinite(edges)) or edges.max() <= 0.0:
        return np.full(3, float(longest))
    edges = edges / edges.max()
    return np.maximum(edges, 0.1) * float(longest)


def rotation_z_to(axis) -> np.ndarray:
    """The shortest rotation (4,) x y z w that turns the z axis onto ``axis`` (3,), any length > 0."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    w = 1.0 + a[2]  # cos of the angle, plus 1: twice the squared cosine of the half angle
    if w < 1e-12:  # axis = -z: half a turn about x
        return np.array([1.0, 0.0, 0.0, 0.0])
    q = np.array([-a[1], a[0], 0.0, w])  # z x a, 1 + z . a
    return q / np.linalg.norm(q)


def _wheel_markers(axes_B: np.ndarray, reach: float) -> list[SceneMarker]:
    out = []
    for i, axis in enumerate(np.asarray(axes_B, dtype=float).T):
        u = axis / np.linalg.norm(axis)
        colour = _WHEEL_COLOURS[i % len(_WHEEL_COLOURS)]
        tip = tuple(float(v) for v in reach * u)
        name = f"wheel_{i + 1}"
        out.append(SceneMarker("wheel_axes", i, ARROW, scale=(0.02, 0.05, 0.08), color=colour,
                               points=((0.0, 0.0, 0.0), tip)))
        out.append(SceneMarker("wheels", i, CYLINDER, position=tuple(float(v) for v in 0.7 * reach * u),
                               orientation=tuple(float(v) for v in rotation_z_to(u)), scale=(0.22, 0.22, 0.04),
                               color=colour))
        out.append(SceneMarker("wheel_labels", i, TEXT, position=tuple(float(v) for v in 1.08 * reach * u),
                               scale=(0.0, 0.0, 0.08), color=colour, text=name))
    return out


def body_scene(values: Mapping[str, Mapping[str, Any]], propagated=None) -> BodyScene:
    """The frames and body model of a scenario, from its nodes' parameter values (``node -> name -> value``).

    The scenario has an orbit, and the scene an ``lvlh`` frame, when the
    guidance tracks LVLH (``guidance.mode: lvlh``) or a disturbance model
    flies the orbit frame (``gravity_gradient``, ``aerodynamic``); the orbit
    is then the guidance's in ``lvlh`` mode, else the disturbance node's.

    Parameters
    ----------
    values : mapping
        At least ``plant.inertia``; ``wheels.geometry`` and
        ``wheels.actuator``, ``guidance.mode``, ``disturbance.models`` and
        the ``orbit.*`` of the node that flies the orbit where present (a
        node missing: what it would add is left out).
    propagated : callable, optional
        Builds the propagated orbit of that node's values when its
        ``orbit.model`` is not ``circular`` (``core.sim.build.build_scene``
        passes the ephemeris); without it the scene draws the circular frame.
    """
    plant = values.get("plant", {})
    wheels = values.get("wheels", {})
    box = box_from_inertia(plant.get("inertia", (1.0, 1.0, 1.0)))
    markers = [SceneMarker("body", 0, CUBE, scale=tuple(float(v) for v in box), color=(0.72, 0.72, 0.76, 0.55))]
    actuator = wheels.get("actuator", "reaction_wheels")
    # reaction wheels on their geometry's axes; the speed-loop wheels one per body axis (paper 003)
    geometry = GEOMETRIES.get(str(wheels.get("geometry", ""))) if actuator == "reaction_wheels" else (
        orthogonal_triad if actuator == "speed_loop" else None)
    if geometry is not None:
        markers += _wheel_markers(geometry(), 0.5 * float(box.max()) + 0.35)
    guidance, disturbance = values.get("guidance", {}), values.get("disturbance", {})
    if guidance.get("mode") == "lvlh":
        orbit = guidance
    elif set(disturbance.get("models", ())) & set(_ORBIT_MODELS):
        orbit = disturbance
    else:
        return BodyScene(tuple(markers))
    q_LN0 = quat_from_euler(np.radians(np.asarray(orbit["orbit.lvlh_initial_rpy_deg"], dtype=float)))
    moving = propagated(orbit) if propagated is not None and orbit.get("orbit.model", "circular") != "circular" \
        else None
    return BodyScene(tuple(markers), np.asarray(q_LN0, dtype=float),
                     orbit_rate(float(orbit["orbit.mu"]), float(orbit["orbit.radius"])), moving)
