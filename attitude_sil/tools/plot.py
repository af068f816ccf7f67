"""Plot a recorded run (a rosbag2 MCAP bag) as one figure of stacked time series.

:func:`plot_bag` reads the known topics of a run, matched by their last path
component so namespaced runs (``/sat1/attitude``) work too, and draws one
panel per quantity on a shared sim-time axis: attitude (Euler angles with the
setpoint), attitude error, body rates, the controller command (voltage and/or
torque), wheel speeds, disturbance torque and, for the flexible plant, the
flexible mode.  Panels whose topics are absent or empty are left out.
Controller swaps found in ``/parameter_events`` (:func:`controller_swaps`)
are marked on every panel.  Matplotlib runs headless (Agg backend).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.transforms import blended_transform_factory

from attitude_sil.core.plant.quaternion import euler_from_quat
from attitude_sil.errors import BagError
from attitude_sil.ros.contract import (
    ATTITUDE,
    ATTITUDE_ERROR,
    ATTITUDE_SETPOINT,
    BODY_RATE,
    DISTURBANCE_TORQUE,
    FLEXIBLE_MODE,
    TORQUE_CMD,
    VOLTAGE_CMD,
    WHEEL_STATE,
)
from attitude_sil.ros.convert import quaternion_to_array, vector_to_array
from attitude_sil.storage.reader import BagReader, open_bag

__all__ = ['controller_swaps', 'effective_swaps', 'initial_controller', 'plot_bag']

_PANEL_HEIGHT_IN = 2.2
_FIG_WIDTH_IN = 11.0
_DPI = 110
_AXIS_COLOURS = ('C0', 'C1', 'C2')
_RPM_PER_RAD_S = 60.0 / (2.0 * np.pi)
_CONTROLLER_PARAMETER = 'controller_type'
_WHEEL_STYLES = ('-', '--', '-.', ':')


# ------------------------------------------------------------------ controller swaps
def _controller_events(reader: BagReader) -> tuple[str | None, list[tuple[float, str]]]:
    """Initial controller type and the swaps, from the bag's parameter events."""
    topic = reader.find_topic('parameter_events')
    if topic is None or reader.topics[topic].count == 0:
        return None, []
    initial: str | None = None
    current: str | None = None
    swaps: list[tuple[float, str]] = []
    for raw, event in reader.iter_decoded(topic):
        if not str(event.node).rstrip('/').endswith('controller'):
            continue
        for param in event.new_parameters:
            if param.name == _CONTROLLER_PARAMETER and param.value.string_value and initial is None:
                initial = current = str(param.value.string_value)
        for param in event.changed_parameters:
            if param.name != _CONTROLLER_PARAMETER or not param.value.string_value:
                continue
            new = str(param.value.string_value)
            if new != current:
                swaps.append((raw.log_time_ns / 1e9, new))
                current = new
    return initial, swaps


def controller_swaps(reader: BagReader) -> list[tuple[float, str]]:
    """Controller swaps recorded in ``/parameter_events``.

    A swap is an event of a node whose name ends in ``controller`` with a
    changed ``controller_type`` parameter whose string value differs from
    the type in force.

    Parameters
    ----------
    reader : BagReader
        An opened bag.

    Returns
    -------
    list of (float, str)
        ``(t, new_type)`` in log-time order; ``t`` is the event's log time
        (its stamp: sim time, s).  Empty if the bag has no parameter events.
    """
    return _controller_events(reader)[1]


def initial_controller(reader: BagReader) -> str | None:
    """Controller type declared at start-up (a new ``controller_type`` parameter), if recorded.

    Parameters
    ----------
    reader : BagReader
        An opened bag.

    Returns
    -------
    str or None
    """
    return _controller_events(reader)[0]


# ------------------------------------------------------------------ data
@dataclass
class _Series:
    """Samples of one topic: times (s, shape (N,)) and values (shape (N, k))."""

    t: list[float] = field(default_factory=list)
    v: list[Any] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.t, dtype=float), np.asarray(self.v, dtype=float)

    def __bool__(self) -> bool:
        return bool(self.t)


_EXTRACT = {
    ATTITUDE: quaternion_to_array,
    ATTITUDE_SETPOINT: quaternion_to_array,
    ATTITUDE_ERROR: vector_to_array,
    BODY_RATE: vector_to_array,
    VOLTAGE_CMD: vector_to_array,
    TORQUE_CMD: vector_to_array,
    DISTURBANCE_TORQUE: vector_to_array,
    FLEXIBLE_MODE: vector_to_array,
}


def _read_series(reader: BagReader) -> tuple[dict[str, _Series], dict[str, _Series]]:
    """Read the known topics; returns (series by short name, wheel speeds by joint name)."""
    names: dict[str, str] = {}
    for short in (*_EXTRACT, WHEEL_STATE):
        topic = reader.find_topic(short)
        if topic is not None and reader.topics[topic].count > 0:
            names[topic] = short
    series = {short: _Series() for short in names.values()}
    wheels: dict[str, _Series] = {}
    for raw, m in reader.iter_decoded(list(names)):
        short = names[raw.topic]
        t = raw.log_time_ns / 1e9
        if short == WHEEL_STATE:
            for i, speed in enumerate(m.velocity):
                joint = m.name[i] if i < len(m.name) else f'wheel {i}'
                s = wheels.setdefault(joint, _Series())
                s.t.append(t)
                s.v.append(speed * _RPM_PER_RAD_S)
        else:
            s = series[short]
            s.t.append(t)
            s.v.append(_EXTRACT[short](m))
    return series, wheels


def _euler_deg(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (deg), shape (N, 3), of quaternions (N, 4); roll and yaw unwrapped."""
    rpy = euler_from_quat(q)
    rpy[:, 0] = np.unwrap(rpy[:, 0])
    rpy[:, 2] = np.unwrap(rpy[:, 2])
    return np.degrees(rpy)


# ------------------------------------------------------------------ plotting
def _bag_name(path: Path) -> str:
    if path.is_dir():
        return path.resolve().name
    if path.name == 'metadata.yaml':
        return path.resolve().parent.name
    stem = path.stem
    return stem[:-2] if stem.endswith('_0') else stem


def _legend(ax: Any, handles: list[Any] | None = None, labels: list[str] | None = None,
            x: float = 1.01) -> None:
    kwargs: dict[str, Any] = {'loc': 'upper left', 'bbox_to_anchor': (x, 1.0), 'fontsize': 'small',
                              'frameon': False, 'borderaxespad': 0.0, 'handlelength': 2.2}
    if handles is not None:
        ax.legend(handles, labels, **kwargs)
    else:
        ax.legend(**kwargs)


def plot_bag(bag_path: str | Path, out_png: str | Path, title: str | None = None) -> Path:
    """Plot a recorded run to a PNG.

    Panels (top to bottom, each only if its topic has messages): attitude
    roll/pitch/yaw (deg, solid) with the setpoint (dashed, same colours);
    attitude error (deg); body rates (deg/s); controller command (voltage
    in V and/or torque in N m, torque on a right-hand axis when both are
    recorded); wheel speeds (rpm, one line per joint; left out if all zero);
    disturbance torque (N m); flexible mode alpha (deg).  Controller swaps
    are dashed vertical lines on every panel, labelled with the new type on
    the top panel.

    Parameters
    ----------
    bag_path : str or Path
        Bag directory or ``.mcap`` file.
    out_png : str or Path
        Output PNG; parent directories are created.
    title : str, optional
        Figure title; default the bag name and the controller type(s).

    Returns
    -------
    Path
        ``out_png``.  The figure is 11 in wide and 2.2 in per panel at 110 dpi.

    Raises
    ------
    BagError
        If the bag cannot be read or has no attitude messages.
    """

    bag_path = Path(bag_path)
    out_png = Path(out_png)
    reader = open_bag(bag_path)
    attitude_topic = reader.find_topic(ATTITUDE)
    if attitude_topic is None or reader.topics[attitude_topic].count == 0:
        where = bag_path if len(reader.paths) > 1 or bag_path.is_dir() else reader.paths[0]
        raise BagError(f'{where}: no attitude messages (topic .../attitude), nothing to plot')
    initial, swaps = _controller_events(reader)
    series, wheels = _read_series(reader)
    swaps = _effective(swaps, series)

    t_att, q_att = series[ATTITUDE].arrays()
    t0, t1 = float(t_att.min()), float(t_att.max())
    if t1 <= t0:
        t1 = t0 + 1.0
    wheels = {name: s for name, s in wheels.items() if np.any(np.asarray(s.v) != 0.0)}
    panels = _panels(series, wheels)

    fig = Figure(figsize=(_FIG_WIDTH_IN, _PANEL_HEIGHT_IN * len(panels)), dpi=_DPI)
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)
    axes = axes[:, 0]
    try:
        for ax, panel in zip(axes, panels, strict=True):
            _draw_panel(ax, panel, t_att, q_att, series, wheels)

        shown_swaps = [(t, name) for t, name in swaps if t0 <= t <= t1]
        _mark_swaps(axes, shown_swaps)
        axes[-1].set_xlim(t0, t1)
        axes[-1].set_xlabel('sim time (s)')
        if title is None:
            controllers = ([initial] if initial else []) + [name for _, name in shown_swaps]
            title = _bag_name(bag_path) + (f' — controller: {" → ".join(controllers)}' if controllers else '')
        # The title of the top panel, raised over the swap labels (fig.suptitle would collide).
        axes[0].set_title(title, pad=17 if shown_swaps else 6)
        fig.tight_layout()
        out_png.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out_png, dpi=_DPI)
    finally:
        fig.clear()
    return out_png


def _panels(series: dict[str, _Series], wheels: dict[str, _Series]) -> list[str]:
    """The panels to draw, top to bottom: each quantity with messages (wheels: with a non-zero speed)."""
    panels: list[str] = [ATTITUDE]
    panels += [p for p in (ATTITUDE_ERROR, BODY_RATE) if p in series]
    if VOLTAGE_CMD in series or TORQUE_CMD in series:
        panels.append('command')
    if wheels:
        panels.append('wheels')
    panels += [p for p in (DISTURBANCE_TORQUE, FLEXIBLE_MODE) if p in series]
    return panels


def _draw_panel(ax: Any, panel: str, t_att: np.ndarray, q_att: np.ndarray, series: dict[str, _Series],
                wheels: dict[str, _Series]) -> None:
    """Draw one panel of :func:`plot_bag` (a name from :func:`_panels`) on ``ax``, with its grid."""
    if panel == ATTITUDE:
        _plot_attitude(ax, t_att, q_att, series)
    elif panel in (ATTITUDE_ERROR, BODY_RATE):
        _plot_angular(ax, panel, series)
    elif panel == 'command':
        _plot_command(ax, series, Line2D)
    elif panel == 'wheels':
        _plot_wheels(ax, wheels)
    elif panel == DISTURBANCE_TORQUE:
        _plot_disturbance(ax, series)
    elif panel == FLEXIBLE_MODE:
        _plot_flexible_mode(ax, series)
    ax.grid(True, alpha=0.3)
    ax.margins(x=0.0)


def _plot_attitude(ax: Any, t_att: np.ndarray, q_att: np.ndarray, series: dict[str, _Series]) -> None:
    """Roll, pitch, yaw (deg, solid) with the setpoint (dashed, same colours) if recorded."""
    rpy = _euler_deg(q_att)
    for k, name in enumerate(('roll', 'pitch', 'yaw')):
        ax.plot(t_att, rpy[:, k], color=_AXIS_COLOURS[k], lw=1.3, label=name)
    handles, labels = ax.get_legend_handles_labels()
    if ATTITUDE_SETPOINT in series:
        t_sp, q_sp = series[ATTITUDE_SETPOINT].arrays()
        sp = _euler_deg(q_sp)
        for k in range(3):
            # Above the attitude lines, so a setpoint equal to another axis' angle shows.
            ax.plot(t_sp, sp[:, k], color=_AXIS_COLOURS[k], lw=1.1, ls='--', zorder=3)
        handles.append(Line2D([], [], color='0.3', lw=1.1, ls='--'))
        labels.append('setpoint')
    ax.set_ylabel('attitude (deg)')
    _legend(ax, handles, labels)


def _plot_angular(ax: Any, panel: str, series: dict[str, _Series]) -> None:
    """Attitude error (deg) or body rates (deg/s), one line per axis."""
    t, v = series[panel].arrays()
    label, axis_names = ({ATTITUDE_ERROR: ('attitude error (deg)', ('roll', 'pitch', 'yaw')),
                          BODY_RATE: ('body rate (deg/s)',
                                      (r'$\omega_x$', r'$\omega_y$', r'$\omega_z$'))}[panel])
    for k in range(3):
        ax.plot(t, np.degrees(v[:, k]), color=_AXIS_COLOURS[k], lw=1.2, label=axis_names[k])
    ax.set_ylabel(label)
    _legend(ax)


def _plot_wheels(ax: Any, wheels: dict[str, _Series]) -> None:
    """Wheel speeds (rpm), one line per joint."""
    # Wheels of a symmetric layout often turn alike: line styles keep them apart.
    for k, (name, s) in enumerate(wheels.items()):
        t, v = s.arrays()
        ax.plot(t, v, color=f'C{k % 10}', lw=1.3, ls=_WHEEL_STYLES[k % len(_WHEEL_STYLES)], label=name)
    ax.set_ylabel('wheel speed (rpm)')
    _legend(ax)


def _plot_disturbance(ax: Any, series: dict[str, _Series]) -> None:
    """Disturbance torque (N m) per axis; a note instead of a scale when it is all zero."""
    t, v = series[DISTURBANCE_TORQUE].arrays()
    for k, name in enumerate(('x', 'y', 'z')):
        ax.plot(t, v[:, k], color=_AXIS_COLOURS[k], lw=1.2, label=rf'$\tau_{{d,{name}}}$')
    ax.set_ylabel('disturbance (N m)')
    if np.any(v != 0.0):
        _sci(ax)
    else:
        ax.set_ylim(-1.0, 1.0)
        ax.text(0.5, 0.75, 'no disturbance torque (all zero)', transform=ax.transAxes,
                ha='center', va='center', color='0.35')
    _legend(ax)


def _plot_flexible_mode(ax: Any, series: dict[str, _Series]) -> None:
    """The flexible mode alpha (deg)."""
    t, v = series[FLEXIBLE_MODE].arrays()
    ax.plot(t, np.degrees(v[:, 0]), color='C4', lw=1.2, label=r'$\alpha$')
    ax.set_ylabel(r'flex mode $\alpha$ (deg)')
    _legend(ax)


def effective_swaps(reader: BagReader) -> list[tuple[float, str]]:
    """:func:`controller_swaps` at the step each new law first commands (sim time, s): what a plot shows.

    A swap's parameter event is logged at the sim time of the last step
    published before the set: 4.99 s for a swap at 5 s, where the plant holds
    before step 5.00 s. The new law commands from the next command step on.
    """
    return _effective(controller_swaps(reader), _read_series(reader)[0])


def _effective(swaps: list[tuple[float, str]], series: dict[str, _Series]) -> list[tuple[float, str]]:
    """Each swap at the first command step after its parameter event (:func:`effective_swaps`)."""
    stamps = np.unique(np.concatenate([series[c].arrays()[0] for c in (VOLTAGE_CMD, TORQUE_CMD) if c in series]
                                      or [np.zeros(0)]))
    out = []
    for t, name in swaps:
        later = stamps[stamps > t]
        out.append((float(later[0]) if later.size else t, name))
    return out


def _mark_swaps(axes: Any, shown_swaps: list[tuple[float, str]]) -> None:
    """Controller swaps as dashed vertical lines on every panel, labelled with the new type above the top one."""
    for ax in axes:
        for t, _ in shown_swaps:
            ax.axvline(t, color='0.25', ls='--', lw=1.0, zorder=0.5)
    top = axes[0]
    trans = blended_transform_factory(top.transData, top.transAxes)
    for t, name in shown_swaps:
        # Above the panel, clear of the data; tight_layout makes room under the title.
        top.text(t, 1.02, f'→ {name} ({t:g} s)', transform=trans, ha='center', va='bottom', fontsize='small',
                 color='0.15')


def _sci(ax: Any) -> None:
    """Scientific tick labels for small values, the exponent written once above the axis."""
    ax.ticklabel_format(axis='y', style='sci', scilimits=(-2, 4), useMathText=True)


def _plot_command(ax: Any, series: dict[str, _Series], line_cls: Any) -> None:
    """Voltage (V) on ``ax``; torque (N m) on ``ax`` or, with voltage too, a right-hand axis."""
    handles: list[Any] = []
    labels: list[str] = []
    primary = True
    for topic, unit, quantity, symbol in ((VOLTAGE_CMD, 'V', 'voltage', 'u'),
                                          (TORQUE_CMD, 'N m', 'torque', r'\tau')):
        if topic not in series:
            continue
        t, v = series[topic].arrays()
        target = ax if primary else ax.twinx()
        style = '-' if primary else ':'
        for k, name in enumerate(('x', 'y', 'z')):
            (line,) = target.plot(t, v[:, k], color=_AXIS_COLOURS[k], lw=1.2, ls=style)
            handles.append(line)
            labels.append(f'${symbol}_{name}$ ({unit})')
        target.set_ylabel(f'{quantity} cmd ({unit})')
        if topic == TORQUE_CMD:
            _sci(target)
        primary = False
    # With a right-hand axis the legend goes right of its tick labels.
    _legend(ax, handles, labels, x=1.01 if len(handles) <= 3 else 1.09)
