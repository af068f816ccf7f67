"""The discovery environment: a run stays on this machine unless the user opens it."""

from attitude_sil.ros.environment import localhost_environment


def test_a_domain_id_alone_keeps_discovery_on_this_machine():
    # the domain a run claims for itself (or one the user picks) must not open it to the network
    assert localhost_environment({"ROS_DOMAIN_ID": "61"})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert localhost_environment({})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


def test_a_range_the_user_chose_is_kept():
    assert localhost_environment({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}) == {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}
    for var in ("ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY"):
        assert "ROS_AUTOMATIC_DISCOVERY_RANGE" not in localhost_environment({var: "1"})
