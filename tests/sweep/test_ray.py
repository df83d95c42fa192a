"""Sweeps on a local Ray (2 CPUs, no dashboard), each inside a loopback-only network namespace.

Outside such a namespace Ray also listens on the machine's own address even when told 127.0.0.1, so every
Ray start here is wrapped in `unshare -n` (root needed, as in CI); where that cannot be done the tests
are skipped and say why. The same sweep on the process pool is the reference: the tables must be equal.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shlex
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_env, dgtd_cmd
from test_sweep import assert_same_table, assert_store_intact, sweep_file, table_of

from dgtd.experiments import load
from dgtd.sweep import run_sweep

LOOPBACK = {"127.0.0.1", "[::ffff:127.0.0.1]", "[::1]"}


def _namespace_problem() -> str | None:
    if shutil.which("unshare") is None or shutil.which("ip") is None or shutil.which("ss") is None:
        return "needs unshare (util-linux), ip and ss (iproute2) to make a loopback-only network namespace"
    r = subprocess.run(["unshare", "-n", "sh", "-c", "ip link set lo up"], capture_output=True, text=True)
    if r.returncode != 0:
        return f"cannot make a loopback-only network namespace (unshare -n needs root): {r.stderr.strip()}"
    return None


_problem = _namespace_problem()
pytestmark = [
    pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed: pip install 'dgtd[ray]'"),
    pytest.mark.skipif(_problem is not None, reason=_problem or ""),
]


def in_namespace(script: str) -> list[str]:
    """argv running a shell script in a new network namespace whose only interface is loopback."""
    return ["unshare", "-n", "sh", "-c", f"ip link set lo up && {script}"]


def ray_env() -> dict:
    return cli_env(RAY_USAGE_STATS_ENABLED="0")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ref")
    report = run_sweep(load(sweep_file(tmp)), tmp / "out", echo=lambda s: None, progress=False)
    assert report["ran"] == 12
    return tmp / "out"


def test_ray_sweep_equals_the_pool_and_listens_on_loopback_only(tmp_path, reference):
    """... and leaves nothing in the system's temporary folder (Ray's session folder, by default $TMPDIR/ray)."""
    out, listen, system_tmp = tmp_path / "out", tmp_path / "listen.txt", tmp_path / "system-tmp"
    system_tmp.mkdir()
    before = set(Path("/tmp").glob("dgtd-ray-*"))  # where a local Ray's folder goes when $TMPDIR's path is too long
    cmd = shlex.join(dgtd_cmd("sweep", sweep_file(tmp_path), "--out", out, "--executor", "ray", "--workers", "2"))
    # while the sweep runs, record every listening TCP socket of the namespace
    record = f"ss -ltnH >> {shlex.quote(str(listen))}"
    script = f"{cmd} & p=$!; while kill -0 $p 2>/dev/null; do {record}; sleep 0.3; done; wait $p"
    env = ray_env() | {"TMPDIR": str(system_tmp)}
    r = subprocess.run(in_namespace(script), env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "12 jobs run" in r.stdout and "a local Ray on 127.0.0.1" in r.stdout
    assert list(system_tmp.iterdir()) == [] and set(Path("/tmp").glob("dgtd-ray-*")) <= before
    assert_store_intact(out, 12)
    assert_same_table(table_of(out), table_of(reference))
    addresses = {line.split()[3].rsplit(":", 1)[0] for line in listen.read_text().splitlines() if line.strip()}
    assert addresses, "no listening socket seen while Ray ran"
    assert addresses <= LOOPBACK, f"Ray listened on {addresses - LOOPBACK}"


def _ray_task_workers() -> list[int]:
    """Ray worker processes running a sweep job right now (Ray titles them 'ray::run_job')."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if cmdline.read_bytes().startswith(b"ray::run_job"):
                found.append(int(cmdline.parent.name))
        except (OSError, ValueError):
            continue
    return found


@pytest.mark.slow  # a full sweep twice over, with a kill in between
def test_killed_ray_worker_job_is_retried(tmp_path, reference):
    """SIGKILL one Ray worker while it runs a job: Ray reruns the job, and the table is the same."""
    out = tmp_path / "out"
    cmd = shlex.join(dgtd_cmd("sweep", sweep_file(tmp_path), "--out", out, "--executor", "ray", "--workers", "2"))
    proc = subprocess.Popen(in_namespace(cmd), env=ray_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    victim, deadline = None, time.time() + 300
    while victim is None and proc.poll() is None and time.time() < deadline:
        done = len(list((out / "jobs").glob("*.json"))) if (out / "jobs").exists() else 0
        workers = _ray_task_workers() if done >= 1 else []
        if workers:
            try:
                os.kill(workers[0], signal.SIGKILL)
                victim = workers[0]
            except ProcessLookupError:  # its job just ended: try the next one
                pass
        time.sleep(0.05)
    stdout, stderr = proc.communicate(timeout=600)
    assert victim is not None, "no Ray worker was seen running a job"
    assert proc.returncode == 0, stderr[-2000:]
    assert "0 failed" in stdout
    assert_store_intact(out, 12)
    assert_same_table(table_of(out), table_of(reference))
    index = json.loads((out / "sweep.json").read_text())
    assert np.all([j["status"] == "finished" for j in index["jobs"]])


@pytest.mark.slow  # starts a `ray start` cluster and three sweeps beside it: about 40 s
def test_a_ray_start_cluster_on_loopback(tmp_path, reference):
    """A `ray start --head` cluster on 127.0.0.1 (in a loopback-only namespace, stopped at the end): a sweep sent to
    it by address without RAY_AUTH_MODE=token is refused in one line that says so (Ray 2.60 turns token
    authentication on); with it, the sweep runs there and gives the pool's table; and a sweep without --address
    beside the running cluster starts a local Ray of its own instead of joining it, as it does after the cluster
    was killed uncleanly."""
    ray = shlex.quote(str(Path(dgtd_cmd()[0]).parent / "ray"))
    sweep = shlex.quote(str(sweep_file(tmp_path)))
    dgtd = shlex.join(dgtd_cmd())
    logs = {name: tmp_path / f"{name}.log" for name in ("refused", "token", "beside", "after")}
    q = {name: shlex.quote(str(path)) for name, path in logs.items()}
    out = {name: shlex.quote(str(tmp_path / name)) for name in logs}
    script = " ; ".join(
        [
            f"timeout 90 {ray} start --head --node-ip-address=127.0.0.1 --port=6391 --num-cpus=2 "
            "--include-dashboard=false --disable-usage-stats > /dev/null 2>&1",
            f"timeout 120 {dgtd} sweep {sweep} --out {out['refused']} --executor ray --address 127.0.0.1:6391 "
            f"--no-progress > {q['refused']} 2>&1; echo refused=$? >> {q['refused']}",
            f"RAY_AUTH_MODE=token timeout 300 {dgtd} sweep {sweep} --out {out['token']} --executor ray "
            f"--address 127.0.0.1:6391 --no-progress > {q['token']} 2>&1; echo token=$? >> {q['token']}",
            f"timeout 300 {dgtd} sweep {sweep} --out {out['beside']} --executor ray --workers 2 --no-progress "
            f"> {q['beside']} 2>&1; echo beside=$? >> {q['beside']}",
            "pkill -9 -f 'gcs_serve[r]' ; pkill -9 -f 'rayle[t]' ; sleep 2",  # [r]: not this script's own line
            f"timeout 300 {dgtd} sweep {sweep} --out {out['after']} --executor ray --workers 2 --no-progress "
            f"> {q['after']} 2>&1; echo after=$? >> {q['after']}",
            f"timeout 60 {ray} stop --force > /dev/null 2>&1",
        ]
    )
    subprocess.run(in_namespace(script), env=ray_env(), capture_output=True, text=True, timeout=1200)
    text = {name: path.read_text() for name, path in logs.items()}
    assert "refused=2" in text["refused"], text["refused"]
    errors = [line for line in text["refused"].splitlines() if line.startswith("dgtd: error:")]
    assert len(errors) == 1 and "RAY_AUTH_MODE=token" in errors[0], text["refused"]
    assert "Traceback" not in text["refused"] and "gcs_client" not in text["refused"]
    assert "token=0" in text["token"] and "12 jobs run" in text["token"], text["token"]
    assert_same_table(table_of(tmp_path / "token"), table_of(reference))
    for name in ("beside", "after"):
        assert f"{name}=0" in text[name] and "a local Ray on 127.0.0.1" in text[name], text[name]
        assert_same_table(table_of(tmp_path / name), table_of(reference))
