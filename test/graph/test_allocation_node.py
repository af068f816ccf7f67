"""The wheels node takes a new set of available wheels while it runs (``param set /wheels available``), and
refuses one that does not span the three body axes, naming the rule."""

from __future__ import annotations

import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter

from attitude_sil.core.plant.wheels import GEOMETRIES

PYRAMID = GEOMETRIES["hst_pyramid"]()


def test_the_wheels_node_reallocates_while_it_runs_and_refuses_a_set_that_cannot():
    from attitude_sil.nodes.wheels_node import WheelsNode

    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        node = WheelsNode(context=context)
        before = node.core.assembly.allocation.copy()
        (refused,) = node.set_parameters([Parameter("available", value=[1, 2])])
        assert not refused.successful and "do not span the three body axes" in refused.reason
        results = node.set_parameters([Parameter("allocation", value="available"),
                                       Parameter("available", value=[2, 3, 4])])
        assert all(r.successful for r in results)
        after = node.core.assembly.allocation
        assert not np.array_equal(before, after) and not np.any(after[0])
        np.testing.assert_allclose(PYRAMID @ after @ [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], atol=1e-12)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_the_wheels_node_sets_its_null_space_loop_while_it_runs_and_stops_it_over_three_wheels():
    from attitude_sil.nodes.wheels_node import WheelsNode

    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        node = WheelsNode(context=context)
        results = node.set_parameters([Parameter("null_space.time_constant_s", value=2.0),
                                       Parameter("null_space.speed_rpm", value=50.0)])
        assert all(r.successful for r in results)
        wp = node.core.assembly.params
        assert wp.null_tau == 2.0 and wp.null_target == pytest.approx(50.0 * 2.0 * np.pi / 60.0)
        np.testing.assert_allclose(wp.null, [-0.5, 0.5, -0.5, 0.5], atol=1e-15)
        # a reallocation over three wheels is taken (a failed wheel comes first); the loop has no direction left
        results = node.set_parameters([Parameter("allocation", value="available"),
                                       Parameter("available", value=[2, 3, 4])])
        assert all(r.successful for r in results) and not np.any(node.core.assembly.params.null)
        (refused,) = node.set_parameters([Parameter("null_space.time_constant_s", value=1.0)])
        assert not refused.successful and "no null space" in refused.reason
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
