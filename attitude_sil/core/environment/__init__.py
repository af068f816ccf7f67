"""The spacecraft's environment: time and Earth rotation, the orbit, the geomagnetic field.

* :mod:`.earth_time` - a UTC epoch, Julian dates, decimal years, Greenwich
  sidereal time and the inertial-to-Earth-fixed rotation.
* :mod:`.orbit` - classical elements, the two-body and J2 accelerations and a
  propagator that samples the orbit at an episode's step times.
* :mod:`.geomagnetic` - IGRF-14 to degree 13 (coefficients shipped in
  ``data/``) and the centred tilted dipole, in Earth-fixed and inertial axes.

ROS-free: the nodes and the batch engine read the same functions.
"""
