"""ROS-free core: quaternions, rigid body, wheels and motors, disturbances, controllers,
metrics, the parameter schema, scenarios, the batch engine, the trajectory type and the
lockstep rules. Nothing under here imports rclpy (test/test_layers.py checks it).
"""
