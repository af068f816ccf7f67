"""ament_python package set-up of attitude_sil (also a plain pip-installable package)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "attitude_sil"

NODES = ("plant", "wheels", "disturbance", "guidance", "controller", "sensors", "estimator", "magnetorquers")

#: what the node executables import (package.xml declares the same; test/test_package.py checks both)
REQUIRES = [
    "numpy>=1.26",
    "scipy>=1.11",
    "PyYAML>=6.0",
    "mcap>=1.2",
    "mcap-ros2-support>=0.5",
    "numba>=0.59",
    "foxglove-sdk>=0.30",  # run --foxglove: the live view (storage/foxglove.py)
    # Dask distributed: campaigns and tuning on a cluster; brings the `dask scheduler` / `dask worker` CLI
    "dask>=2024.1",
    "distributed>=2024.1",
]
#: the tuner, its plots and the root-locus design; the attitude-sil command imports them too
TUNE = ["pymoo>=0.6.1", "control>=0.10", "matplotlib>=3.7"]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "bench"]),
    # the Fast DDS profile (ros/environment.py) and the IGRF-14 coefficients (core/environment/geomagnetic.py)
    package_data={PACKAGE: ["ros/fastdds_discovery.xml", "core/environment/data/igrf14.shc"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/foxglove", glob("config/foxglove/*.json")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    python_requires=">=3.11",
    # The ROS 2 Jazzy wheels (ros-jazzy-rclpy[fastrtps], ros-jazzy-common-interfaces)
    # are installed by the Makefile; a ROS 2 install provides them instead.
    # a node-only install: pip install . ; everything (the attitude-sil command): pip install '.[tune]'
    install_requires=REQUIRES,
    extras_require={"tune": TUNE, "test": [*TUNE, "pytest>=8.0", "pytest-xdist>=3.5", "ruff>=0.5", "rosbags>=0.10", "websockets>=12.0",
                                            "ppigrf>=2.1"],
                    "docs": ["mkdocs>=1.5"]},  # make docs: the site
    zip_safe=True,
    maintainer="attitude_sil developers",
    description="Spacecraft attitude-control software-in-the-loop simulator on ROS 2 Jazzy",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"attitude-sil = {PACKAGE}.cli:main", f"tuner_node = {PACKAGE}.graph.tuner_node:main"]
        + [f"{n}_node = {PACKAGE}.nodes.{n}_node:main" for n in NODES],
    },
)
