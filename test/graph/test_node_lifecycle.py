"""What a lockstep node must provide is declared, and leaving a piece out fails when the class is defined.

``LockstepNode`` (attitude_sil/ros/node.py) checks its subclasses in
``__init_subclass__``: a node without ``rebuild``, ``step_inputs`` or a
schema is a TypeError at import, naming the node and what it lacks, instead
of an AttributeError at the first step of a run.
"""

from __future__ import annotations

import pytest

from attitude_sil.nodes.controller_node import ControllerNode
from attitude_sil.nodes.disturbance_node import DisturbanceNode
from attitude_sil.nodes.estimator_node import EstimatorNode
from attitude_sil.nodes.sensors_node import SensorsNode
from attitude_sil.nodes.wheels_node import WheelsNode
from attitude_sil.ros.contract import ATTITUDE
from attitude_sil.ros.node import LockstepNode


def test_the_package_lockstep_nodes_declare_their_lifecycle():
    nodes = (ControllerNode, DisturbanceNode, EstimatorNode, SensorsNode, WheelsNode)
    assert {n for n in LockstepNode.__subclasses__()} >= set(nodes)
    for node in nodes:
        assert node.step_inputs is not None and callable(node.rebuild)
    assert ControllerNode.step_inputs and SensorsNode.step_inputs  # the two that gather several inputs


def test_a_node_without_rebuild_fails_at_its_definition():
    with pytest.raises(TypeError, match=r"lockstep node Forgetful must declare rebuild\(\)"):
        class Forgetful(LockstepNode):
            schema_name = "wheels"
            step_inputs = ()


def test_a_node_without_step_inputs_or_schema_fails_at_its_definition():
    with pytest.raises(TypeError, match="Vague must declare schema_name .*; step_inputs"):
        class Vague(LockstepNode):
            def rebuild(self) -> None:
                pass

    class Complete(LockstepNode):  # the same with every piece: defined without complaint
        schema_name = "disturbance"
        step_inputs = (ATTITUDE,)

        def rebuild(self) -> None:
            pass

    assert Complete.step_inputs == (ATTITUDE,)
