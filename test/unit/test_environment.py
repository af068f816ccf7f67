"""The discovery environment: a run stays on this machine unless the user opens it, and finds its graph fast."""

import xml.etree.ElementTree as ET

from attitude_sil.ros.environment import DISCOVERY_PROFILE, discovery_profile, localhost_environment


def test_a_domain_id_alone_keeps_discovery_on_this_machine():
    # the domain a run claims for itself (or one the user picks) must not open it to the network
    assert localhost_environment({"ROS_DOMAIN_ID": "61"})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert localhost_environment({})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


def test_a_range_the_user_chose_is_kept():
    chosen = localhost_environment({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"})
    assert chosen["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"
    for var in ("ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY"):
        assert "ROS_AUTOMATIC_DISCOVERY_RANGE" not in localhost_environment({var: "1"})


def test_the_package_discovery_profile_is_used_unless_the_user_named_one():
    env = discovery_profile({})
    assert env == {"FASTDDS_DEFAULT_PROFILES_FILE": str(DISCOVERY_PROFILE),
                   "FASTRTPS_DEFAULT_PROFILES_FILE": str(DISCOVERY_PROFILE)}
    # the file ships with the package and says what the module promises: announcements every 0.3 s
    ns = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    root = ET.parse(DISCOVERY_PROFILE).getroot()
    (participant,) = root.findall("f:participant", ns)
    assert participant.get("is_default_profile") == "true"
    lease = participant.find("f:rtps/f:builtin/f:discovery_config/f:leaseAnnouncement", ns)
    assert (int(lease.find("f:sec", ns).text), int(lease.find("f:nanosec", ns).text)) == (0, 300_000_000)
    # a user's profile file, under either name, or another RMW: left alone
    for var in ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
        assert discovery_profile({var: "/mine.xml"}) == {var: "/mine.xml"}
    assert discovery_profile({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}) == {
        "RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}
    # localhost_environment sets both
    both = localhost_environment({})
    assert both["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" and both["FASTRTPS_DEFAULT_PROFILES_FILE"]
