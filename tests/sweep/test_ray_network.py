"""A local Ray started by a sweep, seen from a network: in a network namespace of its own with a second,
non-loopback interface (a veth pair with a private address; nothing leaves the machine), find what it listens on
and check that a client without the cluster's token cannot submit work to it."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("ray")
ADDRESS = "10.200.0.1"
SETUP = (
    f"ip link set lo up && ip link add veth0 type veth peer name veth1 && ip addr add {ADDRESS}/24 dev veth0 "
    "&& ip link set veth1 up && ip link set veth0 up && ip route add default via 10.200.0.2 dev veth0"
)


def namespace_available() -> bool:
    if shutil.which("unshare") is None or shutil.which("ip") is None or shutil.which("ss") is None:
        return False
    r = subprocess.run(["unshare", "-n", "sh", "-c", SETUP], capture_output=True)
    return r.returncode == 0


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_local_ray_refuses_work_from_clients_without_its_token():
    if not namespace_available():
        pytest.skip("needs root, unshare, ip (veth) and ss to make a private network namespace")
    probe = Path(__file__).with_name("ray_probe.py")
    src = Path(__file__).resolve().parents[2] / "src"
    cmd = f"{SETUP} && PYTHONPATH={src} {sys.executable} {probe} {ADDRESS}"
    r = subprocess.run(["unshare", "-n", "sh", "-c", cmd], capture_output=True, text=True, timeout=540)
    line = next((x for x in r.stdout.splitlines() if x.startswith("RESULT ")), None)
    assert line is not None, r.stdout[-2000:] + r.stderr[-2000:]
    result = json.loads(line[len("RESULT ") :])
    assert result["ran"] and result["auth_mode"] == "token"
    # What it listens on (Ray 2.60: every interface, not only loopback): reported, and then the token must hold.
    print("a local Ray listens on", result["listening"])
    assert set(result["intruders"].values()) <= {"refused", "refused (timed out)"}, result
