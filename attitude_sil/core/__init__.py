"""ROS-free core: quaternions, rigid body, wheels and motors, disturbances, controllers,
metrics, the parameter schema, scenarios, the batch engine, the trajectory type and the
lockstep rules. Nothing under here imports rclpy (test/test_layers.py checks it).
"""

from attitude_sil.core.cache import use_numba_cache

use_numba_cache()  # before any compiled function of the package is declared (core/cache.py says why)
