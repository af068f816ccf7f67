"""What the flight software sees: sensor models (gyro, star tracker, wheel tachometer) and the attitude
estimator (a multiplicative extended Kalman filter).

ROS-free and vectorised over a leading episode axis P, like the rest of ``core``: the ``sensors`` and
``estimator`` nodes hold one of these objects with P = 1 and the batch engine's stepwise driver holds one
with P episodes, and both call the same methods in the same order (docs/sensors.md).
"""
