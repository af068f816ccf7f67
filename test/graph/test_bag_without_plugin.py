"""A bag outlives the plugins installed when it was recorded (issue 40, deliverable 4).

A law plugin, ``tmp_pd``, is installed for the recording only: a distribution
(its ``.dist-info`` with the entry point, and its module) in a folder put on
``PYTHONPATH`` of the recording processes, found by ``importlib.metadata`` as
any installed package is. The verifying processes run without that folder:
the plugin is uninstalled for them. Its law is the example's ``quat_pd`` step
under another name (nothing new to compile).

* A PID run recorded with the plugin installed keeps ``tmp_pd.*`` in its
  snapshot; verified without the plugin it passes, with one notice line.
* A run that flew ``tmp_pd`` (from the start, or swapped to) is refused in
  one line naming the law and what is installed, exit 2, no traceback.
"""

import json
import os
import subprocess
import sys

import pytest

from attitude_sil.core.control import registry
from conftest import ROOT

PLUGIN = "tmp_pd"

MODULE = '''"""A law plugin installed for one test: the example's quat_pd under another name."""
from dataclasses import replace

from quat_pd import LAW as _QUAT_PD

LAW = replace(_QUAT_PD, name="tmp_pd", summary="quat_pd under another name (a test's plugin)")
'''


def _attitude_sil(*args, env: dict, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "attitude_sil.cli", *map(str, args)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """(environment without the plugin, environment with it, {name: bag}) for three runs recorded with it."""
    root = tmp_path_factory.mktemp("plugin")
    site = root / "site"
    info = site / "tmp_pd_law-0.1.dist-info"
    info.mkdir(parents=True)
    (site / "tmp_pd_law.py").write_text(MODULE)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: tmp-pd-law\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[attitude_sil.laws]\n{PLUGIN} = tmp_pd_law:LAW\n")
    without = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    with_plugin = {**without, "PYTHONPATH": str(site)}
    runs = {"pid": ("--swap", "0.5:fuzzy_pid"), "flew": ("--controller", PLUGIN),
            "swapped": ("--swap", f"0.5:{PLUGIN}")}
    out = {}
    for name, flags in runs.items():
        bag = root / name
        res = _attitude_sil("run", ROOT / "config" / "hst_roll_step.yaml", "--duration", "1", *flags, "--record",
                            bag, "--quiet", env=with_plugin, timeout=600)  # a cold numba cache compiles first
        assert res.returncode == 0, res.stderr
        out[name] = bag
    return without, with_plugin, out


def test_the_plugin_is_installed_for_the_recording_only(bags):
    without, with_plugin, bag = bags
    probe = [sys.executable, "-c", "from attitude_sil.core.control import registry; print(*registry.names())"]
    assert PLUGIN in subprocess.run(probe, env=with_plugin, capture_output=True, text=True, timeout=120,
                                    check=True).stdout.split()
    assert PLUGIN not in subprocess.run(probe, env=without, capture_output=True, text=True, timeout=120,
                                        check=True).stdout.split()
    # the PID run's snapshot holds the plugin's parameters: what made such a bag fail once the plugin was gone
    assert f"{PLUGIN}.kp" in (bag["pid"] / "metadata.yaml").read_text()


def test_a_pid_bag_verifies_after_the_plugin_is_uninstalled_with_one_notice(bags):
    without, with_plugin, bag = bags
    res = _attitude_sil("replay", bag["pid"], "--verify-controller", env=without, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert res.stdout.startswith("PASS") and "1 recorded parameter change(s) applied" in res.stdout
    notes = [line for line in res.stderr.splitlines() if line.startswith("note:")]
    assert notes == [f"note: {bag['pid']}: ignoring the recorded parameters of {PLUGIN}, a law not installed here "
                     "(the bag did not fly it)"], res.stderr
    assert "Traceback" not in res.stderr
    # with the plugin installed the snapshot is read whole: no notice
    res = _attitude_sil("replay", bag["pid"], "--verify-controller", env=with_plugin, timeout=300)
    assert res.returncode == 0 and res.stdout.startswith("PASS"), res.stdout + res.stderr
    assert "note:" not in res.stderr


@pytest.mark.parametrize("run, when", [("flew", ""), ("swapped", " (a swap recorded at t=0.490 s)")])
def test_a_bag_that_flew_the_uninstalled_law_is_refused_in_one_line(bags, run, when):
    without, with_plugin, bag = bags
    res = _attitude_sil("replay", bag[run], "--verify-controller", env=without, timeout=300)
    assert res.returncode == 2 and res.stdout == "", res.stdout + res.stderr
    assert PLUGIN not in registry.names()  # this process, like the verifying one, runs without the plugin
    assert res.stderr.splitlines() == [
        f"attitude-sil: error: {bag[run]}: the bag flew controller_type {PLUGIN}{when}, which is not installed "
        f"(installed: {', '.join(registry.names())}); install it to verify this bag"], res.stderr
    # where it is installed the same bag verifies: the refusal is about the environment, not the bag
    res = _attitude_sil("replay", bag[run], "--verify-controller", env=with_plugin, timeout=300)
    assert res.returncode == 0 and res.stdout.startswith("PASS"), res.stdout + res.stderr


def test_metrics_of_the_bags_read_without_the_plugin(bags):
    # attitude-sil metrics reads the same snapshot: the PID bag with the same note, the plugin's bag with a note
    # that names the law it flew (metrics run no law), both exit 0 with the metrics of what was recorded
    without, _, bag = bags
    res = _attitude_sil("metrics", bag["pid"], "--json", env=without, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert f"ignoring the recorded parameters of {PLUGIN}, a law not installed here" in res.stderr
    assert json.loads(res.stdout.splitlines()[-1])["controller_type"] == "pid"
    res = _attitude_sil("metrics", bag["flew"], "--json", env=without, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert f"the bag flew controller_type {PLUGIN}, not installed here; its metrics need no law" in res.stderr
    assert json.loads(res.stdout.splitlines()[-1])["controller_type"] == PLUGIN
