"""Inside a network namespace with a non-loopback interface: what a local Ray of dgtd listens on, and whether a
client without the cluster's token can submit work to it."""

import json
import os
import subprocess
import sys

import ray

from dgtd.sweep.ray import RayExecutor

ex = RayExecutor(num_cpus=1)
ok = ex.submit(lambda a, b: a**b, 2, 10).result(timeout=120) == 1024

gcs = ray.get_runtime_context().gcs_address
port = gcs.rsplit(":", 1)[1]
listen = subprocess.run(["ss", "-ltnH"], capture_output=True, text=True).stdout
addresses = sorted({line.split()[3].rsplit(":", 1)[0] for line in listen.splitlines() if line.strip()})
intruder = (
    "import ray, sys\n"
    f"ray.init(address='{sys.argv[1]}:{port}', log_to_driver=False)\n"
    "print('SUBMITTED', ray.get(ray.remote(lambda: 1).remote(), timeout=20))\n"
)
outcomes = {}
for mode, token in (("token", "not-the-token"), ("disabled", "")):
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_AUTH")}
    env.update(RAY_AUTH_MODE=mode, **({"RAY_AUTH_TOKEN": token} if token else {}), HOME="/tmp/ray-intruder-home")
    try:
        r = subprocess.run([sys.executable, "-c", intruder], capture_output=True, text=True, env=env, timeout=60)
        outcomes[mode] = "submitted" if "SUBMITTED" in r.stdout else "refused"
    except subprocess.TimeoutExpired:
        outcomes[mode] = "refused (timed out)"
ex.shutdown()
print(
    "RESULT",
    json.dumps(
        {"ran": ok, "listening": addresses, "intruders": outcomes, "auth_mode": os.environ.get("RAY_AUTH_MODE")}
    ),
)
