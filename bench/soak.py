"""Soak: a `graft train` run held for a given wall time while faults come (an env actor
SIGKILLed every 2 minutes, the replay server SIGKILLed once, half way), sampling every
minute each of its processes' resident memory, open file descriptors and threads (summed
by role: the learner, the replay server, the env actors, the evaluator, Ray's own), Ray's
object-store use and the run folder's size.

Writes soak.csv (minute, role, metric, value) and soak.png, prints each series' slope
after the first tenth of the run, and exits 1 if any grows faster than its stated limit
(`SLOPE_LIMITS`, per hour) over the second half of the run, or the run does not survive
to a clean Ctrl-C stop.

    nice -n 5 python bench/soak.py --minutes 30 --out runs/soak
    nice -n 5 python bench/soak.py --minutes 30 --preset minecraft-backbone --clients 4 \
        --set replay_max_size=20000 --out runs/soak-minecraft   # 4 simulated clients, real time
    python bench/soak.py --report runs/soak      # the verdict of a finished soak, again

A table left to fill (`replay_max_size` past what the soak inserts) grows the replay
server and the run folder by design: bound it so the soak sees the steady state.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Optional

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SLOPE_LIMITS = {
    "rss_mib": 64.0,
    "fds": 30.0,
    "threads": 30.0,
    "processes": 6.0,
    "object_store_mib": 64.0,
    "run_dir_mib": 256.0,
}
"""Largest growth per hour a series may show after the first tenth. The run folder grows
by design (the replay log and checkpoints of a table filling to max_size, metrics.csv):
its limit is what pendulum-td3 writes at full speed, well under a leak of every sample."""
ROLES = (
    ("learner", "graft.cli train"),
    ("replay server", "replay serve"),
    ("env actors", "ray::EnvActor"),
    ("evaluator", "ray::Evaluator"),
    ("weight broadcaster", "ray::WeightBroadcaster"),
    ("step budget", "ray::StepBudget"),
    ("ray idle workers", "ray::IDLE"),
    ("ray gcs", "gcs_server"),
    ("ray raylet", "raylet/raylet"),
    ("ray dashboard agent", "dashboard/agent.py"),
    ("ray dashboard", "dashboard/dashboard.py"),
    ("ray other actors", "ray::"),
    ("ray other", ""),
)
"""A process's role: the first whose text its command line holds ('ray': the rest)."""


def _children() -> dict[int, list[int]]:
    tree: dict[int, list[int]] = defaultdict(list)
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            tree[ppid].append(int(entry.name))
    return tree


def descendants(pid: int) -> list[int]:
    """`pid` and every process below it."""
    tree, found, todo = _children(), [pid], [pid]
    while todo:
        for child in tree.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def role_of(pid: int) -> str:
    line = cmdline(pid)
    return next(role for role, text in ROLES if text in line)


def process_figures(pid: int) -> Optional[dict[str, float]]:
    """Resident MiB, open fds and threads of one process (None: it has exited)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
    if fields.get("State", "").split()[:1] == ["Z"]:
        return None
    rss = int(fields.get("VmRSS", "0 kB").split()[0]) / 1024
    return {"rss_mib": rss, "fds": fds, "threads": int(fields["Threads"]), "processes": 1}


def object_store_mib(pids: list[int]) -> float:
    """The Ray object store's resident pages: the Rss of the raylet's plasma mappings
    (/dev/shm/plasma*), from /proc/PID/smaps (nan when no raylet is found)."""
    raylets = [p for p in pids if "raylet" in cmdline(p).split(" ", 1)[0]]
    if not raylets:
        return float("nan")
    total_kib, in_plasma = 0, False
    try:
        lines = Path(f"/proc/{raylets[0]}/smaps").read_text().splitlines()
    except OSError:
        return float("nan")
    for line in lines:
        if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
            in_plasma = "/dev/shm/plasma" in line
        elif in_plasma and line.startswith("Rss:"):
            total_kib += int(line.split()[1])
    return total_kib / 1024


def folder_mib(folder: Path) -> float:
    total = 0
    for path in folder.rglob("*"):
        try:
            total += path.stat().st_size if path.is_file() else 0
        except OSError:
            continue
    return total / 2**20


def sample(root: int, run_dir: Path) -> dict[tuple[str, str], float]:
    """One minute's figures, summed by role."""
    pids = descendants(root)
    figures: dict[tuple[str, str], float] = defaultdict(float)
    for pid in pids:
        got = process_figures(pid)
        if got is not None:
            role = role_of(pid)
            for metric, value in got.items():
                figures[(role, metric)] += value
    figures[("ray raylet", "object_store_mib")] = object_store_mib(pids)
    figures[("run folder", "run_dir_mib")] = folder_mib(run_dir)
    return dict(figures)


def kill_one(root: int, text: str) -> Optional[int]:
    """SIGKILLs the oldest process below `root` whose command line holds `text`."""
    found = sorted(p for p in descendants(root) if text in cmdline(p))
    if not found:
        return None
    os.kill(found[0], signal.SIGKILL)
    return found[0]


def _slope_per_h(points: list[tuple[float, float]]) -> float:
    x, y = np.array(points).T
    return float(np.polyfit(x, y, 1)[0]) * 60


def slopes(rows: list[tuple[float, str, str, float]]) -> list[dict]:
    """Each series' least-squares slope per hour after the first tenth and over the second
    half; a series fails if it still grows past its limit in the second half (growth that
    levels off, a cache or Ray's capped history filling, is no leak; a leak grows on)."""
    series: dict[tuple[str, str], list[tuple[float, float]]] = defaultdict(list)
    for minute, role, metric, value in rows:
        if np.isfinite(value):
            series[(role, metric)].append((minute, value))
    end = max((m for m, *_ in rows), default=0.0)
    verdicts = []
    for (role, metric), points in sorted(series.items()):
        kept = [(m, v) for m, v in points if m >= end / 10]
        late = [(m, v) for m, v in points if m >= end / 2]
        if len(late) < 3:
            continue
        slope, late_slope, limit = _slope_per_h(kept), _slope_per_h(late), SLOPE_LIMITS[metric]
        verdicts.append(
            {"role": role, "metric": metric, "first": kept[0][1], "last": kept[-1][1],
             "slope_per_h": slope, "late_slope_per_h": late_slope, "limit_per_h": limit,
             "ok": late_slope <= limit}
        )  # fmt: skip
    return verdicts


def print_verdicts(verdicts: list[dict]) -> None:
    print(
        f"{'role':<18} {'metric':<17} {'first':>9} {'last':>9} {'slope/h':>9} "
        f"{'2nd half/h':>10} {'limit/h':>8}"
    )
    for v in verdicts:
        print(
            f"{v['role']:<18} {v['metric']:<17} {v['first']:>9.1f} {v['last']:>9.1f} "
            f"{v['slope_per_h']:>9.1f} {v['late_slope_per_h']:>10.1f} {v['limit_per_h']:>8.0f}"
            f"{'' if v['ok'] else '  GROWS'}"
        )


def plot(rows: list[tuple[float, str, str, float]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = list(SLOPE_LIMITS)
    fig, axes = plt.subplots(len(metrics), 1, figsize=(8, 2.4 * len(metrics)), sharex=True)
    for ax, metric in zip(axes, metrics, strict=True):
        by_role: dict[str, list[tuple[float, float]]] = defaultdict(list)
        for minute, role, m, value in rows:
            if m == metric:
                by_role[role].append((minute, value))
        for role, points in sorted(by_role.items()):
            x, y = zip(*points, strict=True)
            ax.plot(x, y, marker=".", label=role)
        ax.set_ylabel(metric)
        ax.legend(fontsize=7, loc="upper left")
    axes[-1].set_xlabel("minutes")
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def start_run(run_dir: Path, preset: str, extra: Sequence[str] = ()) -> subprocess.Popen:
    """`graft train` of `preset` with an endless budget, `extra` appended."""
    argv = [
        sys.executable, "-m", "graft.cli", "train", "--preset", preset, "--address",
        "local", "--run-dir", str(run_dir), "--no-progress", "--env-steps", str(10**9),
        "--set", "actors.max_restarts=1000", "--set", "replay.max_restarts=100", *extra,
    ]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("RAY_ADDRESS", None)
    return subprocess.Popen(
        argv, cwd=run_dir.parent, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, start_new_session=True,
    )  # fmt: skip


RAY_STARTS = 3
"""Tries at a run whose local Ray did not come up (a busy machine: Ray's start timeout)."""


def start_and_wait(
    run_dir: Path, preset: str, extra: Sequence[str] = (), limit_s: float = 900.0
) -> subprocess.Popen:
    """The run, once its learner has updated; a run whose Ray failed to start is tried
    again (`RAY_STARTS` in all)."""
    for attempt in range(1, RAY_STARTS + 1):
        if run_dir.exists():
            shutil.rmtree(run_dir)
        process = start_run(run_dir, preset, extra)
        metrics, deadline = run_dir / "metrics.csv", time.monotonic() + limit_s
        try:
            while not (metrics.exists() and "losses/" in metrics.read_text()):
                if process.poll() is not None:
                    _, err = process.communicate()
                    if "timed out during startup" in err and attempt < RAY_STARTS:
                        print(f"soak: Ray did not start (try {attempt}); again", flush=True)
                        break
                    raise SystemExit(f"soak: the run ended before it started: {err[-2000:]}")
                if time.monotonic() > deadline:
                    raise SystemExit("soak: no learner update within the start limit")
                time.sleep(1.0)
            else:
                return process
        except BaseException:
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)
            raise
    raise AssertionError("unreachable")


def _interrupted(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"soak: signal {signum}")


def soak(args: argparse.Namespace) -> tuple[list[tuple[float, str, str, float]], dict]:
    """Runs the soak; returns the samples and what happened to the run."""
    out: Path = args.out
    run_dir = out / "run"
    extra = [*(["--clients", str(args.clients)] if args.clients else [])]
    for setting in args.set:
        extra += ["--set", setting]
    process = start_and_wait(run_dir, args.preset, extra)
    rows: list[tuple[float, str, str, float]] = []
    events = {"actor_kills": 0, "replay_kills": 0}
    try:
        start = time.monotonic()
        next_sample, next_kill, replay_at = 0.0, args.kill_every_s, args.minutes * 30.0
        while (now := time.monotonic() - start) < args.minutes * 60:
            if process.poll() is not None:
                break
            if now >= next_sample:
                for (role, metric), value in sample(process.pid, run_dir).items():
                    rows.append((round(now / 60, 3), role, metric, value))
                next_sample += args.sample_every_s
            if now >= next_kill:
                events["actor_kills"] += kill_one(process.pid, "ray::EnvActor") is not None
                next_kill += args.kill_every_s
            if replay_at is not None and now >= replay_at:
                events["replay_kills"] += kill_one(process.pid, "replay serve") is not None
                replay_at = None
            time.sleep(1.0)
        for (role, metric), value in sample(process.pid, run_dir).items():
            rows.append((round((time.monotonic() - start) / 60, 3), role, metric, value))
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)  # stops as Ctrl-C does (exit 143)
        _, err = process.communicate(timeout=600)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    events.update(
        returncode=process.returncode, env_steps=summary.get("env_steps"),
        updates=summary.get("updates"), stderr_tail=err.strip().splitlines()[-3:],
    )  # fmt: skip
    return rows, events


def report_again(folder: Path) -> int:
    """The verdict of an earlier soak's soak.csv (and its events, from soak.json)."""
    with open(folder / "soak.csv") as f:
        rows = [
            (float(r["minute"]), r["role"], r["metric"], float(r["value"]))
            for r in csv.DictReader(f)
        ]
    events = json.loads((folder / "soak.json").read_text())["events"]
    verdicts = slopes(rows)
    print(f"soak {folder}: {json.dumps({k: v for k, v in events.items() if k != 'stderr_tail'})}")
    print_verdicts(verdicts)
    return exit_status(events, verdicts)


def exit_status(events: dict, verdicts: list[dict]) -> int:
    """0 if the run survived to a clean stop with its replay kill and no series grew."""
    survived = events["returncode"] == 143 and events["replay_kills"] == 1
    return 0 if survived and all(v["ok"] for v in verdicts) else 1


def main(argv: Optional[list[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--sample-every-s", type=float, default=60.0)
    parser.add_argument("--kill-every-s", type=float, default=120.0, help="env actor kills")
    parser.add_argument("--preset", default="pendulum-td3")
    parser.add_argument(
        "--clients", type=int, default=0, help="Minecraft presets: simulated clients (0: none)"
    )
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="as graft train's"
    )
    parser.add_argument("--out", type=Path, default=Path("runs/soak"))
    parser.add_argument(
        "--report", type=Path, metavar="DIR", help="only the verdict of DIR/soak.csv, again"
    )
    args = parser.parse_args(argv)
    if args.report is not None:
        return report_again(args.report)
    args.out = args.out.resolve()
    args.out.mkdir(parents=True, exist_ok=True)
    signal.signal(signal.SIGTERM, _interrupted)  # `kill SOAK` stops its run too
    rows, events = soak(args)
    with open(args.out / "soak.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(("minute", "role", "metric", "value"))
        writer.writerows(rows)
    plot(rows, args.out / "soak.png")
    verdicts = slopes(rows)
    report = {"events": events, "slopes": verdicts}
    (args.out / "soak.json").write_text(json.dumps(report, indent=1))
    clients = f" with {args.clients} clients" if args.clients else ""
    print(f"soak: {args.minutes:g} min of {args.preset}{clients}; {json.dumps(events)}")
    print_verdicts(verdicts)
    print(f"wrote {args.out / 'soak.csv'} and {args.out / 'soak.png'}")
    return exit_status(events, verdicts)


if __name__ == "__main__":
    raise SystemExit(main())
