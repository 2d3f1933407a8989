"""Laundry-grasping trials in simulation, end to end through the ZeroMQ services.

    python -m launch_scripts.trials --seeds S [S ...] --json REPORT.json [--task corner|unfold]
        [--regrasp adjacent|lowest|redetect ...] [--kind corner|boundary|highest] [--state STATE] [--cloth KIND] [--workers N]
        [--engine local|ray] [--pictures DIR] [--markdown SUMMARY.md] [--frames N] [--log-dir DIR] [--quiet]

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
per ``--regrasp`` choice of the second corner, reported side by side.

Trials run in local processes, one per trial, ``--workers`` at a time (default 1; each
trial also runs two service processes; a trial whose process dies is recorded as
failed, "error: WorkerDied: ...", and the others go on), or on a local Ray instance
(``--engine ray``, needs ``ray``). Outputs: REPORT.json (``success_rate``,
``wilson_95``, ``summary`` and the ``trials``, each with at least ``seed`` and
``success``), optionally a markdown summary and a picture per trial (the plan on the
frame, the closed fingers, the lifted cloth), and the logs of the services and of the
trial processes (``--log-dir``, default ``logs/`` beside REPORT.json). Exit status 0
when every trial ran (whether its grasp succeeded or not), 1 when a trial could not run,
2 for bad arguments (one line on stderr).
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing
import multiprocessing.connection
import os
import shlex
import signal
import sys
import time
from pathlib import Path

from tqdm import tqdm

from ipc.messages import GraspPlan
from launch_scripts.cli import OneLineParser, add_log_level_argument, configure_logging, positive_int
from launch_scripts.trial_runner.report import markdown, report, write_json
from launch_scripts.trial_runner.trial import (
    TASKS,
    TRIAL_TRACKER,
    UNFOLD_TRACKER,
    TrialConfig,
    run_trial,
    scene_record,
    trial_config_dict,
)
from launch_scripts.trial_runner.unfold import REGRASPS
from sim.laundry import CLOTH_KINDS, INITIAL_STATES

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
    if not seeds or min(seeds) < 0:
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
    p.add_argument("--regrasp", choices=REGRASPS, nargs="+", default=["adjacent"],
                   help="unfold: how the second corner is chosen; several run each seed once per choice "
                        "(adjacent: the tracked mesh, default; lowest, redetect: baselines)")
    p.add_argument("--kind", "--mode", dest="kind", choices=GraspPlan.KINDS, default="corner",
                   help="grasp kind to request (default corner; --mode is its earlier name, which the results use)")
    p.add_argument("--state", choices=INITIAL_STATES,
                   help="force this initial state in every scene (default: drawn from the seed)")
    p.add_argument("--cloth", choices=CLOTH_KINDS,
                   help="force this cloth kind in every scene (default: drawn from the seed)")
    p.add_argument("--workers", type=positive_int, default=1, help="trials run at once (default 1)")
    p.add_argument("--engine", choices=("local", "ray"), default="local",
                   help="local processes (default) or a local Ray instance (needs ray)")
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
              "failure": failure, "scene": scene_record(seed, config.scene_options)}
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


def _trial_process(connection, trial, seed: int, config: TrialConfig, output: str) -> None:
    """The body of a trial's process: run it and send its record to the runner."""
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
                process = context.Process(target=_trial_process, args=(send, trial, seed, config, output), daemon=True,
                                          name=f"trial seed {seed}")
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


def _run_ray(seeds: list[int], config: TrialConfig, workers: int, progress) -> list[dict]:
    try:
        import ray
    except ImportError as e:
        raise RuntimeError(f"--engine ray needs the Python module 'ray' ({e}); install it with: pip install 'ray>=2.9'") from None
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(run_trial)
        pending = {remote.remote(seed, config): seed for seed in seeds}
        records = []
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                seed = pending.pop(ref)
                try:
                    records.append(ray.get(ref))
                except ray.exceptions.RayError as e:
                    records.append(_lost(seed, config, f"error: {type(e).__name__}: {' '.join(str(e).split())[:300]}"))
                progress(records[-1])
        return records
    finally:
        if started:
            ray.shutdown()


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    seeds = sorted({s for group in args.seeds for s in group})
    if args.json.exists() and args.json.is_dir():
        parser.error(f"--json {args.json} is a directory")
    configure_logging(args.log_level)
    log_dir = args.log_dir if args.log_dir is not None else args.json.parent / "logs"
    scene_options = {k: v for k, v in (("state", args.state), ("cloth_kind", args.cloth)) if v is not None}
    if args.task == "unfold" and args.kind != "corner":
        parser.error("--task unfold grasps corners: --kind must be corner")
    unfold = args.task == "unfold"
    configs = [TrialConfig(task=args.task, regrasp=regrasp, kind=args.kind, observe_frames=args.frames,
                           tracker=UNFOLD_TRACKER if unfold else TRIAL_TRACKER, log_dir=str(log_dir),
                           pictures_dir=None if args.pictures is None else str(args.pictures),
                           scene_options=scene_options)
               for regrasp in (dict.fromkeys(args.regrasp) if unfold else ["adjacent"])]
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
    run = _run_ray if args.engine == "ray" else _run_local
    try:
        records = [record for config in configs for record in run(seeds, config, args.workers, progress)]
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
                "engine": args.engine, "workers": args.workers,
                "wall_s": round(time.perf_counter() - start, 1)}
    rep = report(records, command, settings)
    write_json(args.json, rep)
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(markdown(rep))
    s = rep["summary"]["success"]
    lo, hi = s["wilson_95"]
    for name, u in s.get("by_regrasp", {}).items():
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
