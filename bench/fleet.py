"""Weight broadcast at fleet scale: the object-store fan-out of service/weights.py against
the single long-poll broadcaster it replaced (kept below as the baseline), side by side in
one run on one machine.

For each fleet size N, N simulated actors follow the broadcast the way env actors do:
every step they check for new weights without waiting (the per-step cost is timed), then
"act" for ``--step-ms`` by waiting in ``poll`` (so an arrival ends the step at once and
adoption times are not rounded to steps). Each has its own subscriber; they run in
lightweight Ray actor processes (num_cpus=0, no torch), one each up to ``--processes``
(default 64; a Ray worker holds about 40 MB and takes a second of CPU to start), past
that several to a process, a thread each. Several in one process share its core worker;
the fan-out's subscribers also share one long-poll and fetch per process (as the
service's do), while the baseline's each keep their own. With ``--processes`` at least
the fleet size every actor has a process to itself, as env actors do, and nothing is
shared.
This process, as the learner, publishes ``--versions`` versions of Minecraft-sized weights
(3.7 MB of float32) every ``--interval`` seconds. An actor holds a version from the end
of its fetch: inside `poll` on the acting thread for the baseline, on its process's
background thread for the fan-out (the acting thread takes it at its next step). Both
broadcasts carry the same numpy payload (the old one published tensors, whose unpickling
each actor paid as well).

Printed per size and broadcast: publish time (median), time from publish until every
actor holds the version (median, p90 over versions: a version counts as held once the
actor holds it or a newer one), (actor, version) pairs never adopted and the largest
fraction of actors that skipped one version, the broadcast's CPU (its Ray actors: the
broadcaster, and relays for the fan-out) per version, and the per-step check's cost.

    python bench/fleet.py                      # 4, 16, 64, 256 actors
    python bench/fleet.py --sizes 4 64 --versions 40
    python bench/fleet.py --quick              # a smoke run: 2 and 4 actors, 4 versions
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Optional

import numpy as np
import ray
from ray import ObjectRef

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from service.weights import FANOUT, BroadcastPublisher, WeightSubscriber  # noqa: E402

MINECRAFT_WEIGHTS = {"l0.weight": (1000, 600), "l1.weight": (600, 540), "l2.weight": (540, 6)}
"""Three layers, 927,240 float32 parameters: 3.7 MB, as the Minecraft policy publishes."""
TARGET_RATIO = 4.0
"""Time-to-all at 64 actors over the time at 4 must stay at or below this."""
TARGET_SKIPPED = 0.1
"""No version may be skipped by more than this fraction of the actors."""


# --- the baseline: one broadcaster answering every actor's long-poll -------------------


@ray.remote(num_cpus=0)
class SingleBroadcaster:
    """The broadcast before the fan-out: every subscriber long-polls this one actor."""

    def __init__(self) -> None:
        self._version = -1
        self._weights_ref: list[ObjectRef[Any]] = []
        self._changed: Optional[asyncio.Event] = None
        self._stopped = False

    def _event(self) -> asyncio.Event:
        if self._changed is None:
            self._changed = asyncio.Event()
        return self._changed

    async def publish(self, version: int, weights_ref: list[ObjectRef[Any]]) -> None:
        self._version, self._weights_ref = version, weights_ref
        event = self._event()
        self._changed = asyncio.Event()
        event.set()

    async def stop(self) -> None:
        self._stopped = True
        self._event().set()

    async def wait_newer(self, version: int, timeout_s: float = 30.0) -> tuple[Any, ...]:
        deadline = asyncio.get_running_loop().time() + timeout_s
        while self._version <= version and not self._stopped:
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                break
            try:
                await asyncio.wait_for(self._event().wait(), remaining)
            except TimeoutError:
                break
        return self._version, self._weights_ref, self._stopped


class LongPollSubscriber:
    """The subscriber before the fan-out: one outstanding long-poll, checked with
    `ray.wait` on the acting thread at every step, the weights fetched there too."""

    def __init__(self, broadcaster: Any) -> None:
        self._broadcaster = broadcaster
        self.version = -1
        self.stopped = False
        self.fetched_at = float("nan")
        self._pending: Optional[ObjectRef[Any]] = None

    def poll(self, *, block_s: float = 0.0) -> Optional[Any]:
        if self._pending is None:
            self._pending = self._broadcaster.wait_newer.remote(self.version)
        ready, _ = ray.wait([self._pending], timeout=block_s)
        if not ready:
            return None
        version, weights_ref, self.stopped = ray.get(self._pending)
        weights = None
        if version > self.version and weights_ref:
            weights = ray.get(weights_ref[0])
            self.version, self.fetched_at = version, time.time()
        if not self.stopped:
            self._pending = self._broadcaster.wait_newer.remote(self.version)
        return weights


# --- the fleet ---------------------------------------------------------------------------


@ray.remote(num_cpus=0, max_concurrency=2)
class Follower:
    """Simulated env actors in one process, each on its own thread with its own
    subscriber: every step checks for weights, then acts by waiting in `poll`."""

    def __init__(self) -> None:
        self.held: list[int] = []

    def pid(self) -> int:
        return os.getpid()

    def holds(self) -> int:
        """The oldest version any of its actors holds (-1 before `follow` has started them:
        the two calls run on separate threads, so this one may come first)."""
        return min(self.held, default=-1)

    def follow(self, subscribers: list[Any], step_s: float) -> list[dict[str, Any]]:
        self.held = [-1] * len(subscribers)
        with ThreadPoolExecutor(len(subscribers)) as pool:
            runs = [pool.submit(self._follow, i, s, step_s) for i, s in enumerate(subscribers)]
            return [run.result() for run in runs]

    def _follow(self, i: int, subscriber: Any, step_s: float) -> dict[str, Any]:
        adopted: dict[int, float] = {}
        checks: list[float] = []
        while not subscriber.stopped:
            t = time.perf_counter()
            payload = subscriber.poll()  # the per-step check
            if payload is None:
                checks.append(time.perf_counter() - t)
                payload = subscriber.poll(block_s=step_s)  # acting
            if payload is not None:
                adopted[subscriber.version] = subscriber.fetched_at  # held since
                self.held[i] = subscriber.version
        # The median: a busy machine preempts a few checks for whole scheduler slices.
        return {"adopted": adopted, "check_us": 1e6 * statistics.median(checks or [0.0])}


def cpu_s(pids: list[int]) -> float:
    """User + system CPU seconds of live processes, from /proc."""
    total = 0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except FileNotFoundError:
            continue
        total += int(fields[11]) + int(fields[12])  # utime, stime (fields 14, 15)
    return total / os.sysconf("SC_CLK_TCK")


def actor_pid(handle: Any) -> int:
    return int(ray.get(handle.__ray_call__.remote(lambda self: os.getpid())))


class Broadcast:
    """One broadcast under test: how to publish, subscribe, stop, and whose CPU to count."""

    def __init__(
        self,
        *,
        publish: Callable[[int], None],
        subscriber: Callable[[], Any],
        stop: Callable[[], None],
        pids: Callable[[], list[int]],
        handles: list[Any],
    ) -> None:
        self.publish, self.subscriber, self.stop = publish, subscriber, stop
        self.pids, self.handles = pids, handles


def fan_out(weights: dict[str, Any], fanout: int = FANOUT) -> Broadcast:
    import torch

    tensors = {k: torch.from_numpy(v) for k, v in weights.items()}
    publisher = BroadcastPublisher(fanout=fanout)
    root = publisher.broadcaster

    def pids() -> list[int]:
        return [actor_pid(h) for h in [root, *ray.get(root.relays.remote())]]

    return Broadcast(
        publish=lambda v: publisher.publish(v, tensors),
        subscriber=lambda: WeightSubscriber(root),
        stop=publisher.stop,
        pids=pids,
        handles=[root],
    )


def single(weights: dict[str, Any]) -> Broadcast:
    root = SingleBroadcaster.remote()  # type: ignore[attr-defined]
    return Broadcast(
        publish=lambda v: ray.get(root.publish.remote(v, [ray.put(weights)])),
        subscriber=lambda: LongPollSubscriber(root),
        stop=lambda: ray.get(root.stop.remote()),
        pids=lambda: [actor_pid(root)],
        handles=[root],
    )


def wait_until(condition: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def measure(
    broadcast: Broadcast, fleet: list[Any], actors: int, args: argparse.Namespace
) -> dict[str, Any]:
    """Publishes `args.versions` versions to `actors` simulated actors, spread evenly over
    the processes of `fleet`, following `broadcast`; the figures."""
    step_s = args.step_ms / 1000
    shares = [len(range(i, actors, len(fleet))) for i in range(len(fleet))]
    runs = [
        f.follow.remote([broadcast.subscriber() for _ in range(k)], step_s)
        for f, k in zip(fleet, shares, strict=True)
    ]

    def all_hold(version: int) -> bool:
        return min(ray.get([f.holds.remote() for f in fleet])) >= version

    broadcast.publish(0)  # warm-up: every actor subscribed (relays started) before timing
    if not wait_until(lambda: all_hold(0), args.timeout):
        raise SystemExit(f"bench/fleet.py: {actors} actors did not all receive version 0")
    pids = broadcast.pids()
    fleet_pids = ray.get([f.pid.remote() for f in fleet])
    cpu0, fleet_cpu0, wall0 = cpu_s(pids), cpu_s(fleet_pids), time.monotonic()
    published: dict[int, float] = {}
    publish_s = []
    for version in range(1, args.versions + 1):
        published[version] = time.time()
        t = time.perf_counter()
        broadcast.publish(version)
        publish_s.append(time.perf_counter() - t)
        time.sleep(max(0.0, args.interval - (time.time() - published[version])))
    complete = wait_until(lambda: all_hold(args.versions), args.timeout)
    cpu = cpu_s(pids) - cpu0
    fleet_cpu = (cpu_s(fleet_pids) - fleet_cpu0) / (time.monotonic() - wall0)
    broadcast.stop()
    reports = [r for process in ray.get(runs, timeout=args.timeout) for r in process]
    for handle in broadcast.handles:
        ray.kill(handle)  # relays are owned by the broadcaster: they end with it

    versions = range(1, args.versions + 1)
    to_all, skipped_by = [], []
    for v in versions:
        held_at = [
            min((t for u, t in r["adopted"].items() if u >= v), default=None) for r in reports
        ]
        if None not in held_at:
            to_all.append(max(held_at) - published[v])  # type: ignore[type-var]
        skipped_by.append(sum(v not in r["adopted"] for r in reports))
    return {
        "publish_ms": 1e3 * statistics.median(publish_s),
        "to_all_ms": 1e3 * statistics.median(to_all) if to_all else float("nan"),
        "to_all_p90_ms": 1e3 * float(np.percentile(to_all, 90)) if to_all else float("nan"),
        "complete": complete,
        "skipped_pairs": sum(skipped_by),
        "pairs": actors * args.versions,
        "worst_skipped": max(skipped_by) / actors,
        "cpu_ms_per_version": 1e3 * cpu / args.versions,
        "processes": len(pids),
        "fleet_cores": fleet_cpu,
        "check_us": statistics.median(r["check_us"] for r in reports),
    }


def start_fleet(n: int) -> list[Any]:
    """`n` follower processes, started and answering."""
    fleet = [Follower.remote() for _ in range(n)]  # type: ignore[attr-defined]
    pending = [f.pid.remote() for f in fleet]
    started = 0
    while pending:
        done, pending = ray.wait(pending, num_returns=len(pending), timeout=10.0)
        if done:
            started += len(done)
            print(f"  processes started: {started}/{n}", flush=True)
    return fleet


ROW = "{:>6} {:>10} {:>11} {:>11} {:>11} {:>13} {:>13} {:>13} {:>11} {:>9}"


def start_ray(attempts: int = 6) -> None:
    """A local Ray instance; Ray gives its raylet 30 s to register, which a machine busy
    with other jobs can miss: then it tries again."""
    for attempt in range(1, attempts + 1):
        try:
            ray.init(
                address="local",
                include_dashboard=False,
                log_to_driver=False,
                configure_logging=False,
            )
            return
        except Exception as e:  # Ray raises a bare Exception for this
            if "timed out during startup" not in str(e) or attempt == attempts:
                raise
            print(f"  Ray did not start in time (attempt {attempt}); trying again", flush=True)
            ray.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[4, 16, 64, 256])
    parser.add_argument("--versions", type=int, default=20, help="versions per measurement")
    parser.add_argument("--interval", type=float, default=0.25, help="seconds between publishes")
    parser.add_argument("--step-ms", type=float, default=20.0, help="a simulated actor's step")
    parser.add_argument(
        "--processes",
        type=int,
        default=64,
        help="Ray actor processes at most; more simulated actors share them, a thread each",
    )
    parser.add_argument("--fanout", type=int, default=FANOUT, help="subscribers per relay")
    parser.add_argument("--timeout", type=float, default=120.0, help="per wait, seconds")
    parser.add_argument("--quick", action="store_true", help="2 and 4 actors, 4 versions")
    args = parser.parse_args()
    if args.quick:
        args.sizes, args.versions, args.interval = [2, 4], 4, 0.2
    if min(args.sizes) < 1 or args.versions < 1 or args.processes < 1 or args.interval <= 0:
        parser.error("--sizes, --versions and --processes must be >= 1, --interval > 0")
    weights = {
        k: np.random.default_rng(0).random(s, np.float32) for k, s in MINECRAFT_WEIGHTS.items()
    }
    megabytes = sum(w.nbytes for w in weights.values()) / 1e6

    start_ray()
    try:
        print(
            f"{max(args.sizes)} actors in at most {args.processes} Ray actor processes "
            f"(num_cpus=0) on {os.cpu_count()} cores, "
            f"load {os.getloadavg()[0]:.1f}; {megabytes:.1f} MB weights, {args.versions} "
            f"versions every {args.interval} s, {args.step_ms:.0f} ms steps",
            flush=True,
        )
        fleet = start_fleet(min(max(args.sizes), args.processes))
        print(
            ROW.format(
                "actors",
                "broadcast",
                "publish ms",
                "to-all ms",
                "to-all p90",
                "never adopted",
                "worst skip %",
                "bcast CPU ms",
                "check µs",
                "fleet CPU",
            )
        )
        results: dict[tuple[int, str], dict[str, Any]] = {}
        for n in sorted(args.sizes):
            broadcasts = {"single": single, "fan-out": lambda w: fan_out(w, args.fanout)}
            for name, make in broadcasts.items():
                r = results[n, name] = measure(make(weights), fleet[:n], n, args)
                print(
                    ROW.format(
                        n,
                        name,
                        f"{r['publish_ms']:.1f}",
                        f"{r['to_all_ms']:.1f}" + ("" if r["complete"] else "*"),
                        f"{r['to_all_p90_ms']:.1f}",
                        f"{r['skipped_pairs']}/{r['pairs']}",
                        f"{100 * r['worst_skipped']:.0f}",
                        f"{r['cpu_ms_per_version']:.1f}" + f" ({r['processes']})",
                        f"{r['check_us']:.1f}",
                        f"{r['fleet_cores']:.2f}",
                    ),
                    flush=True,
                )
        print(
            "bcast CPU: the broadcast's actors, per version (how many); fleet CPU: cores "
            "the actors used; * some actor never got the last version within --timeout"
        )
        report_ratios(results, sorted(args.sizes))
        print(f"load after: {os.getloadavg()[0]:.1f}")
    finally:
        ray.shutdown()


def report_ratios(results: dict[tuple[int, str], dict[str, Any]], sizes: list[int]) -> None:
    small, large = sizes[0], sizes[-1]
    for probe in (64, large):
        if probe in sizes and probe != small:
            large = probe
            break
    for name in ("single", "fan-out"):
        ratio = results[large, name]["to_all_ms"] / results[small, name]["to_all_ms"]
        worst = max(results[n, name]["worst_skipped"] for n in sizes)
        print(
            f"{name:>8}: time-to-all {large} actors / {small} actors = {ratio:.1f}x "
            f"(target <= {TARGET_RATIO:.0f}x); worst version skipped by {100 * worst:.0f}% "
            f"of the actors (target <= {100 * TARGET_SKIPPED:.0f}%)"
        )
    for n in sizes:
        old, new = results[n, "single"], results[n, "fan-out"]
        print(
            f"{n:>4} actors, single / fan-out: time-to-all "
            f"{old['to_all_ms'] / new['to_all_ms']:.1f}x, per-step check "
            f"{old['check_us'] / max(new['check_us'], 1e-3):.0f}x"
        )


if __name__ == "__main__":
    main()
