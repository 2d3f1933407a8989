"""Trials on an existing Ray cluster: a head node started here with ``ray start --head`` (free
ports, its own temporary folder, its own token), trials sent to it with ``--ray-address``,
and the head stopped by its process id (and only the processes of its own session)."""

import importlib.util
import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

pytest.importorskip("ray")
pytest.importorskip("pybullet")
pytestmark = [pytest.mark.slow, pytest.mark.timeout(400)]

REPO = Path(__file__).resolve().parents[2]


def free_ports(n: int) -> list[int]:
    """``n`` distinct TCP ports free on this machine just now."""
    sockets = [socket.socket() for _ in range(n)]
    try:
        for s in sockets:
            s.bind(("", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


def session_processes(temp_dir: str) -> list[int]:
    """Ids of the live processes whose command line names ``temp_dir`` (a Ray session's)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if temp_dir.encode() in cmdline.read_bytes():
                found.append(int(cmdline.parent.name))
        except OSError:  # ended while we looked
            continue
    return [pid for pid in found if pid != os.getpid()]


def kill_all(pids) -> None:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


@pytest.fixture(scope="module")
def ray_head():
    """A Ray head node of 2 CPUs for this module's tests: yields its address, the IP address
    it registered with, its folder and the environment a driver needs (its token).

    ``ray start --head --block`` in a session of its own, every port chosen free (a Ray
    already running on this machine is left alone), its folder a new temporary one. Stopped
    at the end by its process id: SIGTERM (``--block`` then stops the processes it
    started), then SIGKILL to its process group and to any process still naming its
    folder. ``ray stop`` is not used: it stops every Ray on the machine.
    """
    # short: Ray's unix socket paths inside it must fit in 107 bytes
    temp_dir = tempfile.mkdtemp(prefix="ray", dir="/tmp")
    (gcs, client, dashboard, agent_http, agent_grpc, env_agent, metrics, node_manager,
     object_manager) = free_ports(9)
    command = [sys.executable, "-m", "ray.scripts.scripts", "start", "--head", "--block",
               "--port", str(gcs), "--dashboard-port", str(dashboard), "--dashboard-agent-listen-port", str(agent_http),
               "--dashboard-agent-grpc-port", str(agent_grpc), "--runtime-env-agent-port", str(env_agent),
               "--metrics-export-port", str(metrics), "--node-manager-port", str(node_manager),
               "--object-manager-port", str(object_manager), "--include-dashboard", "false",
               "--num-cpus", "2", "--object-store-memory", str(100 * 2**20), "--temp-dir", temp_dir,
               "--disable-usage-stats"]
    if importlib.util.find_spec("grpc") is not None:  # ray[client]: its server starts too, on 10001 unless told
        command += ["--ray-client-server-port", str(client)]
    # Token authentication with a token of its own, given to the drivers through the
    # environment: nothing is read from or written to ~/.ray.
    auth = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    # The head and its workers see neither this checkout (no PYTHONPATH, another current
    # folder) nor a cluster address: the trials' code must come shipped from the driver.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "RAY_ADDRESS")} | auth
    output = Path(temp_dir) / "ray_start.log"
    with open(output, "w") as out:
        head = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=temp_dir,
                                env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 90
        while "Ray runtime started" not in output.read_text():
            if head.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"ray start --head did not start: {output.read_text()[-2000:]}")
            time.sleep(0.2)
        # the address the node registers with: Ray turns a loopback one into the machine's own
        node_ip = re.search(r"Local node IP: (\S+)", output.read_text()).group(1)
        driver_env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | auth
        yield {"address": f"127.0.0.1:{gcs}", "node_ip": node_ip, "temp_dir": temp_dir, "env": driver_env}
    finally:
        head.send_signal(signal.SIGTERM)
        try:
            head.wait(timeout=30)
        except subprocess.TimeoutExpired:
            head.kill()
            head.wait()
        try:
            os.killpg(head.pid, signal.SIGKILL)  # its session: raylet, GCS, agents, workers
        except ProcessLookupError:
            pass
        kill_all(session_processes(temp_dir))
        time.sleep(0.5)
        assert session_processes(temp_dir) == []
        shutil.rmtree(temp_dir, ignore_errors=True)


def trials_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "launch_scripts.trials", "--quiet", *args]


def test_two_trials_run_on_the_cluster_and_record_its_node(ray_head, tmp_path):
    done = subprocess.run(trials_command("--seeds", "0", "2", "--frames", "2", "--workers", "2", "--ray-address",
                                         ray_head["address"], "--json", str(tmp_path / "report.json"), "--markdown",
                                         str(tmp_path / "summary.md")),
                          check=False, capture_output=True, text=True, timeout=360, env=ray_head["env"], cwd=REPO)
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["settings"]["engine"] == "ray" and report["settings"]["ray_address"] == ray_head["address"]
    records = report["trials"]
    assert [r["seed"] for r in records] == [0, 2]
    for r in records:
        assert not r["failure"].startswith("error:"), r["failure"]  # a real outcome: success or a judged failure
        assert r["success"] == (r["failure"] == "")
        assert r["node"]["ip"] == ray_head["node_ip"] and len(r["node"]["id"]) == 56  # Ray's node ids: 28 bytes in hex
        assert (Path(r["node"]["log_dir"]) / f"seed{r['seed']}" / "perception.log").exists()
    (node,) = report["summary"]["nodes"]
    assert node["trials"] == 2 and node["id"] == records[0]["node"]["id"]
    assert f"ran on 1 Ray node: {node['host']} ({ray_head['node_ip']}, node {node['id'][:12]}): 2 trials" in (
        tmp_path / "summary.md").read_text()


#: A driver that runs four stand-in trials through ``_run_ray``: seed 1's worker dies, seed
#: 2 raises, the others say where their code came from and which process ran them. (In a
#: process of its own, run as __main__, so that Ray ships the stand-in by value.)
FAULTY_DRIVER = """
import json, os, signal, sys
from launch_scripts.trial_runner import TrialConfig
from launch_scripts.trials import _run_ray

def trial(seed, config):
    import launch_scripts
    if seed == 1:
        os.kill(os.getpid(), signal.SIGKILL)
    if seed == 2:
        raise RuntimeError("the trial broke")
    return {"seed": seed, "success": True, "failure": "", "code": launch_scripts.__file__, "pid": os.getpid()}

config = TrialConfig(log_dir=sys.argv[2], scene_options={"state": "flat"})
seen = []
records = _run_ray([0, 1, 2, 3], config, workers=2, progress=seen.append, address=sys.argv[1], trial=trial)
print(json.dumps({"records": records, "progress": len(seen)}))
"""


def test_a_dead_worker_or_a_raising_trial_is_a_failed_record_and_the_code_comes_shipped(ray_head, tmp_path):
    done = subprocess.run([sys.executable, "-c", FAULTY_DRIVER, ray_head["address"], str(tmp_path / "logs")],
                          check=False, capture_output=True, text=True, timeout=120, env=ray_head["env"], cwd=REPO)
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    by_seed = {r["seed"]: r for r in out["records"]}
    assert sorted(by_seed) == [0, 1, 2, 3] and out["progress"] == 4
    assert by_seed[1]["failure"].startswith("error: WorkerCrashedError: ") and not by_seed[1]["success"]
    assert "\n" not in by_seed[1]["failure"] and by_seed[1]["scene"]["state"] == "flat"
    assert by_seed[2]["failure"] == "error: RuntimeError: the trial broke"
    for seed in (0, 3):
        assert by_seed[seed]["success"] and by_seed[seed]["node"]["ip"] == ray_head["node_ip"]
        # imported from the packages shipped into the head's folder, not from a checkout
        assert by_seed[seed]["code"].startswith(ray_head["temp_dir"]), by_seed[seed]["code"]
        assert by_seed[seed]["node"]["pid"] == by_seed[seed]["pid"]
    # each trial in a worker process of its own, as the local engine runs them
    assert by_seed[0]["pid"] != by_seed[3]["pid"]


def test_an_address_nobody_answers_is_one_line_naming_it(tmp_path):
    (port,) = free_ports(1)
    address = f"127.0.0.1:{port}"
    done = subprocess.run(trials_command("--seeds", "0", "--ray-address", address, "--json",
                                         str(tmp_path / "report.json")),
                          check=False, capture_output=True, text=True, timeout=120, cwd=REPO)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert lines == [f"python -m launch_scripts.trials: error: cannot reach the Ray cluster at {address}: "
                     "Connection refused"]
    assert not (tmp_path / "report.json").exists()
