"""Laundry-grasping trials in simulation, end to end through the ZeroMQ services.

    python -m launch_scripts.trials --seeds S [S ...] --json REPORT.json [--task corner|unfold]
        [--regrasp adjacent|lowest|redetect ...] [--kind corner|boundary|highest] [--state STATE]
        [--cloth KIND] [--arm drawn|panda] [--workers N] [--engine local|ray] [--ray-address ADDRESS] [--pictures DIR]
        [--markdown SUMMARY.md] [--frames N] [--log-dir DIR] [--quiet]

Each seed is one trial (``launch_scripts.trial_runner.trial.run_trial``): a towel or
T-shirt on a table (or held up by a corner), drawn from the seed; its frames go through
a perception service process and a planner service process on free loopback ports;
the plan the controller chooses is executed in the simulation and judged by ground
truth. A seed is an integer or a range START:STOP[:STEP] (Python's). Even seeds are for
development, odd seeds are kept for evaluation. ``--state`` and ``--cloth`` force the
initial state (flat, crumpled, folded, held) or the cloth kind (towel, tshirt) of every
seed; the rest of each scene is still drawn from its seed. ``--task unfold`` runs the
unfold task instead (``trial_runner.unfold``: one arm lifts the cloth by a corner while
every frame is tracked, a second takes an adjacent corner, the edge is stretched), once
per ``--regrasp`` choice of the second corner, reported side by side; with ``--arm panda``
a Franka Panda carries each of its grippers (``sim.panda``), and a motion its arm cannot
reach is the trial's failure, "unreachable: ...".

Trials run in local processes, one per trial, ``--workers`` at a time (default 1; each
trial also runs two service processes; a trial whose process dies is recorded as
failed, "error: WorkerDied: ...", and the others go on), or as Ray tasks (``--engine
ray``, needs ``ray``): on a local Ray instance of ``--workers`` CPUs or, with
``--ray-address ADDRESS`` (or the ``RAY_ADDRESS`` environment variable), on a running
cluster (``ray start --head``), ``--workers`` trials in flight at once and this
process's packages shipped to its workers; each record then names the node that ran
it, and a trial Ray could not run is an "error: ..." record too. Outputs: REPORT.json
(``success_rate``, ``wilson_95``, ``summary`` and the ``trials``, each with at least
``seed`` and ``success``), optionally a markdown summary and a picture per trial (the
plan on the frame, the closed fingers, the lifted cloth), and the logs of the services
and of the trial processes (``--log-dir``, default ``logs/`` beside REPORT.json). Exit
status 0 when every trial ran (whether its grasp succeeded or not), 1 when a trial
could not run, 2 for bad arguments or a cluster that cannot be reached (one line on
stderr).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import multiprocessing
import multiprocessing.connection
import os
import shlex
import shutil
import signal
import socket
import sys
import tempfile
import time
from pathlib import Path

from tqdm import tqdm

from ipc.messages import GraspPlan
from launch_scripts._child import die_with_parent
from launch_scripts.cli import OneLineParser, add_log_level_argument, configure_logging, output_problem, positive_int
from launch_scripts.trial_runner.report import markdown, report, write_json
from launch_scripts.trial_runner.trial import (
    TASKS,
    TrialConfig,
    run_trial,
    scene_record,
    trial_config_dict,
    trial_spec,
)
from launch_scripts.trial_runner.unfold import REGRASPS
from sim.laundry import CLOTH_KINDS, INITIAL_STATES
from sim.laundry.scene import ARMS

log = logging.getLogger("launch_scripts.trials")


def _seeds(text: str) -> list[int]:
    """An integer >= 0, or START:STOP[:STEP] as Python's range."""
    try:
        parts = [int(p) for p in text.split(":")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a seed (integer >= 0) or START:STOP[:STEP], got {text!r}") from None
    if len(parts) == 1:
        seeds = parts
    elif len(parts) in (2, 3) and (len(parts) == 2 or parts[2] != 0):
        seeds = list(range(*parts))
    else:
        raise argparse.ArgumentTypeError(f"expected START:STOP[:STEP] with a non-zero step, got {text!r}")
    if not seeds:
        raise argparse.ArgumentTypeError(f"{text!r} is an empty range (as Python's range: START < STOP for a positive STEP)")
    if min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"expected seeds >= 0, got {text!r}")
    return seeds


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m launch_scripts.trials", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=_seeds, nargs="+", required=True, metavar="S",
                   help="seeds (integers, or START:STOP[:STEP]); even for development, odd for evaluation")
    p.add_argument("--json", type=Path, required=True, metavar="REPORT.json", help="where to write the report")
    p.add_argument("--task", choices=TASKS, default="corner",
                   help="corner: grasp one corner and lift (default); unfold: lift by one corner while tracked, "
                        "take an adjacent corner with a second gripper and stretch the edge")
    p.add_argument("--regrasp", choices=REGRASPS, nargs="+",
                   help="unfold: how the second corner is chosen; several run each seed once per choice "
                        "(adjacent: the tracked mesh, default; lowest, redetect: baselines)")
    p.add_argument("--kind", "--mode", dest="kind", choices=GraspPlan.KINDS, default="corner",
                   help="grasp kind to request (default corner; --mode is its earlier name, which the results use)")
    p.add_argument("--state", choices=INITIAL_STATES,
                   help="force this initial state in every scene (default: drawn from the seed; the unfold "
                        "task draws only states on the table: flat, crumpled, folded)")
    p.add_argument("--cloth", choices=CLOTH_KINDS,
                   help="force this cloth kind in every scene (default: drawn from the seed)")
    p.add_argument("--arm", choices=ARMS, default="drawn",
                   help="the unfold task's robot arms: drawn links to a shoulder (default) or a Franka Panda "
                        "for each gripper, whose inverse kinematics carries it and whose reach is checked")
    p.add_argument("--workers", type=positive_int, default=1, help="trials run at once (default 1)")
    p.add_argument("--engine", choices=("local", "ray"),
                   help="local processes (default), or Ray (needs ray): a local instance, or the cluster of --ray-address")
    p.add_argument("--ray-address", type=_ray_address, metavar="ADDRESS",
                   help="run on the existing Ray cluster there (HOST:PORT of its head, ray://HOST:PORT or auto; "
                        "implies --engine ray; default: the RAY_ADDRESS environment variable with --engine ray)")
    p.add_argument("--pictures", type=Path, metavar="DIR", help="write a picture of each trial there")
    p.add_argument("--markdown", type=Path, metavar="SUMMARY.md", help="write a markdown summary there")
    p.add_argument("--frames", type=positive_int, default=TrialConfig().observe_frames,
                   help=f"frames observed before planning, the first initialises (default {TrialConfig().observe_frames})")
    p.add_argument("--log-dir", type=Path, metavar="DIR", help="services' logs (default: logs/ beside REPORT.json)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_log_level_argument(p)
    return p


def _lost(seed: int, config: TrialConfig, failure: str) -> dict:
    """The record of a trial whose process died before it could report."""
    record = {"seed": seed, "task": config.task, "kind": config.kind, "success": False, "corner_success": False,
              "failure": failure, "scene": scene_record(trial_spec(seed, config))}
    if config.task == "unfold":
        record["regrasp"] = config.regrasp
    return record


def _worker_output_to(path: str) -> None:
    """In a trial's process: its stdout and stderr (PyBullet's banner, warnings of failed
    trials, which their records also hold) go to a file, so the console shows only the
    progress bar and the summary."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(process)d %(levelname)s %(name)s: %(message)s")


def _trial_process(connection, trial, seed: int, config: TrialConfig, output: str, runner: int) -> None:
    """The body of a trial's process: run it and send its record to the runner (pid
    ``runner``), dying with the runner if it is killed."""
    if not die_with_parent(runner):
        return
    _worker_output_to(output)
    connection.send(trial(seed, config))
    connection.close()


def _how_it_ended(exitcode: int | None) -> str:
    """'exit status N' or 'signal NAME' of a process that ended."""
    if exitcode is not None and exitcode < 0:
        try:
            return f"signal {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"signal {-exitcode}"
    return f"exit status {exitcode}"


def _run_local(seeds: list[int], config: TrialConfig, workers: int, progress, trial=run_trial) -> list[dict]:
    """Each trial in a process of its own, ``workers`` at a time; returns their records.

    A process that ends without sending its record (killed, out of memory, a crash in
    native code) gives its seed a record whose failure is "error: WorkerDied: ...", and
    the other trials go on. ``trial(seed, config) -> record`` is ``run_trial`` (tests
    pass another).
    """
    # spawn: each trial starts in a fresh interpreter (PyBullet and ZeroMQ state never
    # cross a fork), and one process per trial returns its memory when it ends.
    context = multiprocessing.get_context("spawn")
    output = str(Path(config.log_dir) / "workers.log") if config.log_dir else os.devnull
    queue, running, records = list(seeds), {}, []
    try:
        while queue or running:
            while queue and len(running) < workers:
                seed = queue.pop(0)
                receive, send = context.Pipe(duplex=False)
                process = context.Process(target=_trial_process, args=(send, trial, seed, config, output, os.getpid()),
                                          daemon=True, name=f"trial seed {seed}")
                process.start()
                send.close()  # only the child writes; its end closes when the child ends
                running[seed] = {"process": process, "connection": receive, "record": None}
            waitables = {}
            for seed, job in running.items():
                waitables[job["process"].sentinel] = seed
                if job["connection"] is not None:
                    waitables[job["connection"]] = seed
            for ready in multiprocessing.connection.wait(list(waitables)):
                seed = waitables[ready]
                job = running.get(seed)
                if job is None:
                    continue
                if ready is job["connection"]:  # read the record as soon as it comes: a full pipe would block the child
                    try:
                        job["record"] = job["connection"].recv()
                    except (EOFError, OSError):  # the child ended without sending
                        pass
                    job["connection"].close()
                    job["connection"] = None
                    continue
                process = job["process"]
                process.join()
                if job["connection"] is not None:  # ended: a record it sent is in the pipe, or nothing is
                    if job["connection"].poll():
                        try:
                            job["record"] = job["connection"].recv()
                        except (EOFError, OSError):
                            pass
                    job["connection"].close()
                record = job["record"]
                if record is None:
                    ending = _how_it_ended(process.exitcode)
                    log.warning("seed %d: the trial's process ended with %s before it reported", seed, ending)
                    record = _lost(seed, config, f"error: WorkerDied: the trial's process ended with {ending}")
                del running[seed]
                records.append(record)
                progress(record)
    finally:
        for job in running.values():  # interrupted: stop the trials still running
            job["process"].terminate()
        for job in running.values():
            job["process"].join(timeout=10)
            if job["process"].is_alive():
                job["process"].kill()
    return records


#: The packages shipped to the workers of a Ray cluster: every top-level package of the
#: distribution, copied from where this process imports them (a checkout or an install).
SHIPPED_PACKAGES = ("ipc", "perception", "grasping", "sim", "launch_scripts")
#: Left out of the copies (glob patterns of names).
SHIPPED_EXCLUDES = ("__pycache__", "*.pyc", "*.egg-info")
#: Longest wait for a TCP connection to a cluster's address before giving up on it.
CONNECT_TIMEOUT_S = 5.0


def _ray_address(text: str) -> str:
    """--ray-address: HOST:PORT of a head node (``ray start --head --port PORT``),
    ray://HOST:PORT (Ray Client) or "auto" (the cluster started on this machine)."""
    address = text.strip()
    if address != "auto" and _host_port(address) is None:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, ray://HOST:PORT or auto, got {text!r}")
    return address


def engine_and_address(engine: str | None, ray_address: str | None, environ) -> tuple[str, str | None]:
    """The engine and the Ray cluster's address of ``--engine`` and ``--ray-address``.

    ``--ray-address`` implies the Ray engine and contradicts the local one (ValueError);
    with the Ray engine and no ``--ray-address``, ``environ["RAY_ADDRESS"]`` when set (as
    Ray reads it), else None: a local Ray instance. The local engine ignores RAY_ADDRESS.
    """
    if ray_address is not None and engine == "local":
        raise ValueError("--ray-address needs --engine ray (the local engine runs on this machine only)")
    engine = engine or ("ray" if ray_address is not None else "local")
    if engine == "ray" and ray_address is None and environ.get("RAY_ADDRESS", "").strip():
        try:
            ray_address = _ray_address(environ["RAY_ADDRESS"])
        except argparse.ArgumentTypeError as e:
            raise ValueError(f"RAY_ADDRESS: {e}") from None
    return engine, ray_address


def _host_port(address: str) -> tuple[str, int] | None:
    """(host, port) of HOST:PORT or ray://HOST:PORT ([IPv6]:PORT too), or None for another form."""
    host, colon, port = address.removeprefix("ray://").rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if not colon or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        return None
    return host, int(port)


def _check_reachable(address: str) -> None:
    """Raise RuntimeError naming ``address`` when nothing answers there: ``ray.init`` would
    retry an unreachable address for minutes."""
    host_port = _host_port(address)
    if host_port is None:  # "auto": Ray looks it up on this machine and says so when it finds none
        return
    try:
        socket.create_connection(host_port, timeout=CONNECT_TIMEOUT_S).close()
    except OSError as e:
        raise RuntimeError(f"cannot reach the Ray cluster at {address}: {e.strerror or e}") from None


@contextlib.contextmanager
def _shipped_packages():
    """A runtime environment for the trials on a cluster: this process's packages, copied to
    a temporary folder that is the job's ``working_dir``. Ray zips and uploads it when the
    job connects (at most 512 MiB; these are about 1 MiB) and unpacks it on each node as
    its workers' current folder, first on their PYTHONPATH, which the trials' service
    processes inherit. So a worker imports the driver's code, not a checkout or an install
    of its own. (A ``working_dir`` rather than ``py_modules``: without one, Ray puts the
    driver's current folder first on the workers' path, where a node's own checkout at the
    same path would shadow the shipped code.)"""
    import importlib

    with tempfile.TemporaryDirectory(prefix="clothkit_shipped_") as staging:
        for name in SHIPPED_PACKAGES:
            (folder,) = importlib.import_module(name).__path__
            shutil.copytree(folder, Path(staging) / name, ignore=shutil.ignore_patterns(*SHIPPED_EXCLUDES))
        yield {"working_dir": staging}


def _one_line(text, limit: int = 300) -> str:
    """``text`` on one line (runs of white space as one space), at most ``limit`` characters."""
    return " ".join(str(text).split())[:limit]


def _ray_failure(error: Exception) -> str:
    """The failure of a trial Ray could not run, one line: "error: " and the exception the
    task raised, or Ray's own (a worker or node that died, a module missing on the worker)
    without the traceback that follows its first line."""
    cause = getattr(error, "cause", None)  # RayTaskError: what the task (or its arguments' unpickling) raised
    error = cause if isinstance(cause, BaseException) else error
    first = next((line for line in str(error).splitlines() if line.strip()), "")
    return f"error: {type(error).__name__}: {_one_line(first)}"


def _writable_here(folder: str | None) -> str | None:
    """``folder`` if it can be made on this node, else a folder of the same name under this
    node's temporary directory (a worker of a cluster need not have the driver's paths)."""
    if folder is None:
        return None
    try:
        Path(folder).mkdir(parents=True, exist_ok=True)
        return folder
    except OSError as e:
        here = Path(tempfile.gettempdir()) / "clothkit_trials" / Path(folder).name
        log.warning("cannot write to %s on this node (%s); writing to %s", folder, e.strerror or e, here)
        return str(here)


def _trial_on_ray(seed: int, config: TrialConfig, trial=run_trial) -> dict:
    """In a Ray worker: ``trial(seed, config)`` (``run_trial``; tests pass another), and the
    node that ran it in the record's ``node`` (Ray's node id, its IP address and host name,
    the worker's process id, and where the trial's logs went on it)."""
    import ray

    config = dataclasses.replace(config, log_dir=_writable_here(config.log_dir),
                                 pictures_dir=_writable_here(config.pictures_dir))
    node_id = ray.get_runtime_context().get_node_id()
    # the address the node joined the cluster with (a machine may have several)
    ip = next((n["NodeManagerAddress"] for n in ray.nodes() if n["NodeID"] == node_id), None)
    node = {"id": node_id, "ip": ip or ray.util.get_node_ip_address(), "host": socket.gethostname(),
            "pid": os.getpid(), "log_dir": config.log_dir}
    record = trial(seed, config)
    record["node"] = node
    return record


def _connect(ray, address: str | None, workers: int) -> None:
    """``ray.init``: a local instance of ``workers`` CPUs, or the cluster at ``address`` with
    this process's packages shipped. Raises RuntimeError, one line naming the address, when
    the cluster cannot be reached or joined."""
    if address is None:
        # "local": a new instance even when a cluster started on this machine exists
        ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False)
        return
    _check_reachable(address)
    try:
        with _shipped_packages() as runtime_env:  # uploaded by ray.init
            ray.init(address=address, runtime_env=runtime_env, log_to_driver=False)
    except Exception as e:  # noqa: BLE001 -- whatever Ray raises (version mismatch, no raylet, upload) is one line
        ray.shutdown()  # a connection half made
        hint = ""
        if (isinstance(e, ConnectionError) or "Authentication" in type(e).__name__) and (
                os.environ.get("RAY_AUTH_MODE") != "token"):
            hint = " (with token authentication: set RAY_AUTH_MODE=token, and its token in RAY_AUTH_TOKEN or ~/.ray/auth_token)"
        raise RuntimeError(f"cannot run on the Ray cluster at {address}{hint}: {type(e).__name__}: {_one_line(e)}") from None


def _run_ray(seeds: list[int], config: TrialConfig, workers: int, progress, address: str | None = None,
             trial=run_trial) -> list[dict]:
    """The trials as Ray tasks, at most ``workers`` in flight; returns their records.

    Without ``address``, on a local Ray instance of ``workers`` CPUs; with one, on the
    cluster there, this process's packages shipped to its workers (``_shipped_packages``).
    Each task needs one CPU of a node and runs ``trial(seed, config)`` there (``run_trial``,
    which starts the two service processes on that node; tests pass another), and its
    record names the node (``node``). A task that raised, or whose worker or node died,
    gives its seed a record whose failure starts with "error:", and the other trials go
    on. Raises RuntimeError (one line) when ``ray`` is missing or the cluster cannot be
    reached.
    """
    try:
        import ray
    except ImportError as e:
        raise RuntimeError(f"--engine ray needs the Python module 'ray' ({e}); install it with: pip install 'ray>=2.9'") from None
    # Absolute paths: a worker's current folder is not this one.
    config = dataclasses.replace(config, log_dir=config.log_dir and os.path.abspath(config.log_dir),
                                 pictures_dir=config.pictures_dir and os.path.abspath(config.pictures_dir))
    queue, pending, records = list(seeds), {}, []
    with contextlib.ExitStack() as stack:
        if not ray.is_initialized():
            _connect(ray, address, workers)
            stack.callback(ray.shutdown)
        # max_calls=1: a worker process runs one trial and exits, as the local engine's do. A
        # trial run after another in the same process is not the same trial: its cloth's
        # physics drifts apart from a fresh process's within a lift (seed 44 after seed 40:
        # 0.09 mm at the lift's 53rd frame, then the tracking, and the grasp, differ).
        remote = ray.remote(num_cpus=1, max_retries=0, max_calls=1)(_trial_on_ray)
        try:
            while queue or pending:
                while queue and len(pending) < workers:
                    seed = queue.pop(0)
                    pending[remote.remote(seed, config, trial)] = seed
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    seed = pending.pop(ref)
                    try:
                        record = ray.get(ref)
                    except ray.exceptions.RayError as e:
                        log.warning("seed %d: the trial did not run: %s", seed, _one_line(e))
                        record = _lost(seed, config, _ray_failure(e))
                    records.append(record)
                    progress(record)
        finally:
            for ref in pending:  # interrupted: stop the trials still running
                ray.cancel(ref, force=True)
    return records


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    seeds = sorted({s for group in args.seeds for s in group})
    try:
        engine, address = engine_and_address(args.engine, args.ray_address, os.environ)
    except ValueError as e:
        parser.error(str(e))
    configure_logging(args.log_level)
    scene_options = {k: v for k, v in (("state", args.state), ("cloth_kind", args.cloth)) if v is not None}
    if args.task == "unfold" and args.kind != "corner":
        parser.error("--task unfold grasps corners: --kind must be corner")
    if args.arm != "drawn" and args.task != "unfold":
        parser.error(f"--arm {args.arm}: only the unfold task's robot has arms")
    if args.regrasp is not None and args.task != "unfold":
        parser.error("--regrasp: only the unfold task takes a second corner (add --task unfold)")
    log_dir = args.log_dir if args.log_dir is not None else args.json.parent / "logs"
    # every folder the run writes in, made once the options are known good: a run of many
    # trials must not fail at its end
    for option, path, is_file in (("--json", args.json, True), ("--markdown", args.markdown, True),
                                  ("--pictures", args.pictures, False), ("--log-dir", log_dir, False)):
        problem = None if path is None else output_problem(path, is_file)
        if problem:
            parser.error(f"{option} {path}: {problem}")
    unfold = args.task == "unfold"
    configs = [TrialConfig(task=args.task, regrasp=regrasp, kind=args.kind, observe_frames=args.frames,
                           log_dir=str(log_dir),
                           pictures_dir=None if args.pictures is None else str(args.pictures),
                           scene_options=scene_options, arm=args.arm)
               for regrasp in (dict.fromkeys(args.regrasp or ["adjacent"]) if unfold else ["adjacent"])]
    command = "python -m launch_scripts.trials " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))

    title = "unfold" if unfold else args.kind
    bar = tqdm(total=len(seeds) * len(configs), desc=f"{title} trials", unit="trial", disable=args.quiet)
    wins = [0]

    def progress(record: dict) -> None:
        wins[0] += bool(record.get("success"))
        bar.update(1)
        bar.set_postfix(success=f"{wins[0]}/{bar.n}")
        if not record.get("success"):
            bar.write(f"seed {record['seed']}: {record.get('failure') or 'failed'}")

    start = time.perf_counter()
    try:
        records = []
        for config in configs:
            if engine == "ray":
                records += _run_ray(seeds, config, args.workers, progress, address)
            else:
                records += _run_local(seeds, config, args.workers, progress)
    except RuntimeError as e:
        bar.close()
        print(f"{parser.prog}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        bar.close()
        print("interrupted; no report written", file=sys.stderr)
        return 130
    bar.close()
    settings = {**trial_config_dict(configs[0]), "regrasps": [c.regrasp for c in configs] if unfold else None,
                "engine": engine, "ray_address": address, "workers": args.workers,
                "wall_s": round(time.perf_counter() - start, 1)}
    rep = report(records, command, settings)
    write_json(args.json, rep)
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(markdown(rep))
    s = rep["summary"]["success"]
    lo, hi = s["wilson_95"]
    for name, u in rep["summary"].get("by_regrasp", {}).items():
        print(f"unfold, second corner by {name}: {u['success']['successes']}/{u['success']['n']} succeeded")
    print(f"{title}: {s['successes']}/{s['n']} trials succeeded ({100 * (s['rate'] or 0):.1f} %, "
          f"95 % Wilson interval {100 * lo:.1f}-{100 * hi:.1f} %) in {settings['wall_s']:.0f} s")
    print(f"report: {args.json}")
    if args.markdown is not None:
        print(f"summary: {args.markdown}")
    if args.pictures is not None:
        print(f"pictures: {args.pictures}/" + ("unfold_seed<S>_<regrasp>.png" if unfold else "trial_seed<S>.png"))
    print(f"logs: {log_dir}")
    could_not_run = rep["summary"]["trials_that_could_not_run"]
    return 1 if could_not_run else 0


if __name__ == "__main__":
    sys.exit(main())
