"""The wheels node takes a new set of available wheels while it runs (``param set /wheels available``), and
refuses one that does not span the three body axes, naming the rule."""

from __future__ import annotations

import numpy as np
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
