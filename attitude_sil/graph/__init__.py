"""Running graphs: start the nodes, play episodes, decode them, tune through them.

* :mod:`~attitude_sil.graph.launcher` - start and stop the nodes (one process, or one per node);
* :mod:`~attitude_sil.graph.session` - :class:`GraphSession` episodes and :func:`run_graph`;
* :mod:`~attitude_sil.graph.trajectory` - recorded messages -> :class:`~attitude_sil.core.trajectory.Trajectory`;
* :mod:`~attitude_sil.graph.evaluator` - graph-mode scoring of tuning candidates;
* :mod:`~attitude_sil.graph.tuner_node` - the ``tuner`` node and the tuning run.
"""
