"""Start the attitude_sil graph as ``attitude-sil run`` does: ``ros2 launch attitude_sil sim.launch.py``.

Needs a full ROS 2 install (``launch`` and ``launch_ros`` are not on PyPI) and
the package built with colcon. The five node executables, from the node list
the runner starts (:data:`attitude_sil.core.sim.scenario.GRAPH_NODES`), each on
simulation time (``use_sim_time: true``, the plant publishes ``/clock``) and
given one parameter file.

Launch arguments:

* ``namespace`` (default none): the whole graph, its ``/clock`` included, under
  this namespace (as ``run --namespace``). The parameter files key their
  sections ``/**/node``, so they apply under any namespace.
* ``params_file`` (default: the installed ``config/hst_roll_step.yaml``): a
  scenario or parameter file, e.g. ``config/hawaiisat_lvlh.yaml``.
* ``controller_type`` (default: the file's): ``pid``, ``fuzzy_pid``,
  ``ga_flc`` or ``geometric`` (as ``run --controller``).
* ``feedback`` (default ``truth``): ``estimate`` also starts the ``sensors``
  and ``estimator`` nodes (:data:`attitude_sil.core.sim.scenario.SENSOR_NODES`)
  and remaps the controller's ``attitude`` and ``body_rate`` to
  ``estimate/attitude`` and ``estimate/body_rate`` (as ``run --feedback``).
* ``sensors`` (default ``false``): ``true`` starts the sensing nodes with
  truth feedback (the estimate is published and recorded, the loop reads the
  truth). The file's ``estimator`` section must give ``initial_attitude_rpy_deg``
  and the star tracker's schedule where they differ from the defaults (the
  runner copies them from the plant and the sensors; ``/**`` sets the schedule
  for both, as ``config/hst_roll_step_sensors.yaml`` does).
* ``magnetorquers`` (default ``false``): ``true`` starts the ``magnetorquers``
  node (:data:`attitude_sil.core.sim.scenario.MAGNETIC_NODES`) and tells the
  plant and the controller they fly, for a file whose controller commands a
  dipole (``momentum.mode``, ``bdot``). The file gives the field model under
  ``/**`` where the disturbances' residual dipole reads it too, and a
  nonzero ``bdot.gain``: for 0 the runner computes k* from the plant's orbit
  and inertia, which a controller node started alone does not know.

Unlike ``attitude-sil run``, nothing starts the episode: the nodes wait for
``plant/reset`` (``autostart`` is off by default; ``attitude-sil episode`` or
``ros2 service call /plant/reset std_srvs/srv/Trigger`` starts it), and nothing
is recorded (``attitude-sil record`` or ``ros2 bag record -s mcap -a`` records
it) or measured (``attitude-sil episode`` prints the metrics).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from attitude_sil.core.sim.scenario import GRAPH_NODES, MAGNETIC_NODES, SENSOR_NODES
from attitude_sil.ros.contract import FEEDBACK_REMAP

PACKAGE = "attitude_sil"
DEFAULT_PARAMS = ("config", "hst_roll_step.yaml")


def generate_launch_description() -> LaunchDescription:
    """The graph's nodes and the launch arguments ``namespace``, ``params_file``, ``controller_type``,
    ``feedback``, ``sensors`` and ``magnetorquers``."""
    namespace = LaunchConfiguration("namespace")
    params_file = LaunchConfiguration("params_file")
    controller_type = LaunchConfiguration("controller_type")
    # /clock moves into the namespace with the graph, as the runner remaps it
    clock = PythonExpression(["'/' + '", namespace, "'.strip('/') + '/clock' if '", namespace,
                              "'.strip('/') else '/clock'"])
    chosen = PythonExpression(["'", controller_type, "' != ''"])
    feedback = LaunchConfiguration("feedback")
    estimate = PythonExpression(["'", feedback, "' == 'estimate'"])
    sensing = PythonExpression(["'", feedback, "' == 'estimate' or '", LaunchConfiguration("sensors"),
                                "'.lower() == 'true'"])
    actions = [
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the whole graph"),
        DeclareLaunchArgument("params_file",
                              default_value=PathJoinSubstitution([FindPackageShare(PACKAGE), *DEFAULT_PARAMS]),
                              description="scenario / parameter YAML given to every node"),
        DeclareLaunchArgument("controller_type", default_value="",
                              description="pid, fuzzy_pid, ga_flc or geometric (default: the file's)"),
        DeclareLaunchArgument("feedback", default_value="truth", choices=["truth", "estimate"],
                              description="what the controller reads: truth or the estimator's output"),
        DeclareLaunchArgument("sensors", default_value="false", choices=["true", "false"],
                              description="run the sensors and the estimator with truth feedback too"),
        DeclareLaunchArgument("magnetorquers", default_value="false", choices=["true", "false"],
                              description="fly the magnetorquers (the file's controller commands a dipole)"),
    ]
    magnetic = LaunchConfiguration("magnetorquers")
    for name in GRAPH_NODES:
        common = dict(package=PACKAGE, executable=f"{name}_node", name=name, namespace=namespace,
                      remappings=[("/clock", clock)], output="screen", emulate_tty=True)
        parameters = [params_file, {"use_sim_time": True}]
        if name in ("plant", "controller"):  # they take the rods' torque, command their dipole
            parameters.append({"magnetorquers": magnetic})
        if name == "controller":
            # with feedback:=estimate it reads the estimator's outputs (remapped onto themselves otherwise)
            common["remappings"] = [*common["remappings"], *(
                (src, PythonExpression(["'", dst, "' if ", estimate, " else '", src, "'"]))
                for src, dst in FEEDBACK_REMAP.items())]
            actions.append(Node(**common, parameters=parameters, condition=UnlessCondition(chosen)))
            actions.append(Node(**common, parameters=[*parameters, {"controller_type": controller_type}],
                                condition=IfCondition(chosen)))
        else:
            actions.append(Node(**common, parameters=parameters))
    for name in SENSOR_NODES:
        actions.append(Node(package=PACKAGE, executable=f"{name}_node", name=name, namespace=namespace,
                            remappings=[("/clock", clock)], output="screen", emulate_tty=True,
                            parameters=[params_file, {"use_sim_time": True}], condition=IfCondition(sensing)))
    for name in MAGNETIC_NODES:
        actions.append(Node(package=PACKAGE, executable=f"{name}_node", name=name, namespace=namespace,
                            remappings=[("/clock", clock)], output="screen", emulate_tty=True,
                            parameters=[params_file, {"use_sim_time": True}], condition=IfCondition(magnetic)))
    return LaunchDescription(actions)
