"""Chaos benchmark: a real replay server process under the faults and loads of ordinary use.

1. SIGKILL/restart cycles while writers insert (periodic checkpoints on, so kills also
   land mid-checkpoint): acknowledged items lost and doubled.
2. Connections cut (TCP reset by a proxy) while inserts wait on a rate limiter, the
   writers resending on reconnect: acknowledged items lost and doubled.
3. 64 idle sample streams + 16 writers: inserts and health checks answered within a
   5 s / 2 s deadline, insert latency.
4. Server RSS growth over scenarios 2 and 3 (one server process each).
5. A Minecraft world server (``minecraft serve``, default limits) under 300 idle
   connections, 16 connections announcing a 4 MiB message and sending 1 byte, and a
   2000x2000 VideoProducer mission: its threads, RSS and replies.

Every table is audited the same way: the server is stopped gracefully, restarted on its
folder with a plain min-size limiter, and read whole. Loopback only.

    python bench/chaos.py [--quick]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import random
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import grpc
import numpy as np
from grpc_health.v1 import health_pb2, health_pb2_grpc

from service.replay._proto import replay_pb2
from service.replay.client import ReplayClient, ReplayError
from service.replay.codec import encode_batch
from service.run.replay_host.process import ReplayProcess

SIGNATURE = {"x": {"dtype": "int64", "shape": []}}
MAX_SIZE = 4_000_000


def rss_mib(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def table(rate_limiter: dict[str, Any], name: str = "t") -> dict[str, Any]:
    return {
        "name": name, "max_size": MAX_SIZE, "sampler": "fifo", "signature": SIGNATURE,
        "rate_limiter": rate_limiter,
    }  # fmt: skip


def server(
    tables: list[dict[str, Any]], folder: Path, *, port: int = 0, extra: tuple[str, ...] = ()
) -> ReplayProcess:
    return ReplayProcess(tables, port=port, extra_args=["--checkpoint-dir", str(folder), *extra])


def audit(folder: Path) -> np.ndarray:
    """Every stored x, read from a fresh server on the folder (no rate limiter in the way)."""
    with server([table({"kind": "min_size", "min_size": 1})], folder) as s:
        client = ReplayClient(s.address, max_message_bytes=1 << 30)
        size = client.info()[0].size
        if size == 0:
            return np.zeros(0, np.int64)
        return client.sample("t", size, timeout=60)["x"]


@dataclass
class Ledger:
    """The batches the writers had acknowledged, and the errors of those they gave up on."""

    acked: list[np.ndarray] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def wait_for_acks(self, more: int, timeout_s: float = 120.0) -> None:
        """Waits until `more` further batches are acknowledged (the writers are back)."""
        with self.lock:
            target = len(self.acked) + more
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if len(self.acked) >= target:
                    return
            time.sleep(0.02)
        raise TimeoutError(f"the writers made no progress in {timeout_s} s")

    def verdict(self, stored: np.ndarray) -> dict[str, int]:
        acked = np.concatenate(self.acked) if self.acked else np.zeros(0, np.int64)
        values, counts = np.unique(stored, return_counts=True)
        return {
            "acked items": len(acked),
            "lost": int(np.setdiff1d(acked, values).size),
            "doubled": int((counts - 1).sum()),
            "stored unacked": int(np.setdiff1d(values, acked).size),
            "writer errors": len(self.errors),
        }


def progress(what: str, ledger: Ledger) -> None:
    with ledger.lock:
        acked, errors = sum(len(a) for a in ledger.acked), len(ledger.errors)
    print(f"    {what}: {acked:,} items acknowledged, {errors} writer errors", flush=True)


def run_writers(
    address: str, ledger: Ledger, stop: threading.Event, *, n: int, pause_s: float
) -> list[threading.Thread]:
    """Writers inserting numbered batches of 10 unique values, resending on UNAVAILABLE."""

    def write(i: int) -> None:
        client = ReplayClient(address, writer_id=f"writer-{i}", max_retries=30)
        j = 0
        while not stop.is_set():
            x = np.arange(10, dtype=np.int64) + (i << 40) + j * 10
            j += 1
            try:
                client.insert("t", {"x": x})
                with ledger.lock:
                    ledger.acked.append(x)
            except ReplayError as error:
                with ledger.lock:
                    ledger.errors.append(str(error))
            time.sleep(pause_s)
        client.close()

    threads = [threading.Thread(target=write, args=(i,), daemon=True) for i in range(n)]
    for t in threads:
        t.start()
    return threads


# ------------------------------------------------------------------- 1. SIGKILL


def kill_restart(cycles: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="chaos-kill-") as tmp:
        folder, port = Path(tmp), free_port()
        limiter = {"kind": "min_size", "min_size": 1}
        extra = ("--checkpoint-every-s", "1")
        current = server([table(limiter)], folder, port=port, extra=extra)
        ledger, stop = Ledger(), threading.Event()
        writers = run_writers(current.address, ledger, stop, n=4, pause_s=0.005)
        for cycle in range(cycles):
            # Each cycle kills a server the writers are busy with: they reconnected and
            # wrote again since the last restart.
            ledger.wait_for_acks(4)
            time.sleep(random.uniform(0.3, 1.2))
            current.kill()
            current.stop()
            current = server([table(limiter)], folder, port=port, extra=extra)
            progress(f"kill {cycle + 1}/{cycles}", ledger)
        time.sleep(0.5)
        stop.set()
        for w in writers:
            w.join(120)
        current.stop()
        return {"cycles": cycles, **ledger.verdict(audit(folder))}


# --------------------------------------------------------- 2. dropped connections


class CuttingProxy:
    """A loopback TCP proxy whose connections can all be cut at once (reset)."""

    def __init__(self, target_port: int) -> None:
        self._target = ("127.0.0.1", target_port)
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = int(self._listener.getsockname()[1])
        self._sockets: set[socket.socket] = set()
        self._lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                downstream, _ = self._listener.accept()
                upstream = socket.create_connection(self._target)
            except OSError:
                return
            with self._lock:
                self._sockets |= {downstream, upstream}
            for src, dst in ((downstream, upstream), (upstream, downstream)):
                threading.Thread(target=self._pump, args=(src, dst), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(1 << 16):
                dst.sendall(data)
        except OSError:
            pass
        finally:
            self._cut([src, dst])

    def _cut(self, sockets: list[socket.socket]) -> None:
        for s in sockets:
            with self._lock:
                self._sockets.discard(s)
            try:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()

    def cut_all(self) -> int:
        with self._lock:
            sockets = list(self._sockets)
        self._cut(sockets)
        return len(sockets) // 2

    def close(self) -> None:
        self._listener.close()
        self.cut_all()


def dropped_connections(cycles: int) -> dict[str, Any]:
    """Writers go through the proxy; a sampler, direct, admits about 10 batches/s through a
    tight sample-to-insert ratio, so inserts wait on the limiter for about 0.4 s each and a
    writer's resend after a cut arrives while its first attempt still waits."""
    with tempfile.TemporaryDirectory(prefix="chaos-drop-") as tmp:
        folder = Path(tmp)
        limiter = {
            "kind": "sample_to_insert_ratio", "samples_per_insert": 1.0, "min_size": 10,
            "error_buffer": 20.0,
        }  # fmt: skip
        s = server([table(limiter)], folder)
        rss_start = rss_mib(s.process.pid)
        proxy = CuttingProxy(int(s.address.rsplit(":", 1)[1]))
        ledger, stop, sampling = Ledger(), threading.Event(), threading.Event()

        def sample() -> None:
            client = ReplayClient(s.address)
            while not sampling.is_set():
                try:
                    client.sample("t", 10, timeout=1.0)
                except ReplayError:
                    pass
                time.sleep(0.1)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        writers = run_writers(f"127.0.0.1:{proxy.port}", ledger, stop, n=4, pause_s=0.0)
        cut = 0
        for cycle in range(cycles):
            ledger.wait_for_acks(1)
            time.sleep(random.uniform(0.3, 0.8))
            cut += proxy.cut_all()
            progress(f"cut {cycle + 1}/{cycles}", ledger)
        time.sleep(1.0)
        stop.set()
        for w in writers:
            w.join(120)
        sampling.set()
        sampler.join(30)
        proxy.close()
        rss_end = rss_mib(s.process.pid)
        s.stop()
        verdict = ledger.verdict(audit(folder))
        return {"cycles": cycles, "connections cut": cut, **verdict,
                "rss": (rss_start, rss_end)}  # fmt: skip


# ---------------------------------------------------------- 3. idle streams + writers


def _load_process(address: str, threads: int, seconds: float, out: Any) -> None:
    """`threads` writers inserting with a 5 s deadline; sends (latencies, error codes)."""
    client = ReplayClient(address)
    payload = encode_batch({"x": np.arange(64, dtype=np.int64)})
    latencies: list[float] = []
    errors: list[str] = []
    lock = threading.Lock()
    end = time.monotonic() + seconds

    def write() -> None:
        request = replay_pb2.InsertRequest(table="t", batch=payload)
        while time.monotonic() < end:
            start = time.perf_counter()
            try:
                client.stub.Insert(iter([request]), timeout=5.0)
                with lock:
                    latencies.append(time.perf_counter() - start)
            except grpc.RpcError as error:
                with lock:
                    errors.append(error.code().name)
            time.sleep(0.01)

    workers = [threading.Thread(target=write) for _ in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    out.put((latencies, errors))


def idle_streams(seconds: float, *, streams: int = 64, writers: int = 16) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="chaos-idle-") as tmp:
        folder = Path(tmp)
        tables = [
            table({"kind": "min_size", "min_size": 1}),
            # Never fills: a sample stream on it waits for good, like a paused learner.
            {**table({"kind": "min_size", "min_size": 1000}, "idle"), "max_size": 1000},
        ]
        s = server(tables, folder)
        client = ReplayClient(s.address)
        close = threading.Event()

        def requests() -> Iterator[replay_pb2.SampleRequest]:
            yield replay_pb2.SampleRequest(table="idle", batch_size=1, num_batches=1)
            close.wait()

        calls = [client.stub.Sample(requests()) for _ in range(streams)]
        time.sleep(1.0)
        rss_start = rss_mib(s.process.pid)
        ctx = mp.get_context("spawn")
        out = ctx.Queue()
        procs = [
            ctx.Process(target=_load_process, args=(s.address, writers // 4, seconds, out))
            for _ in range(4)
        ]
        for p in procs:
            p.start()
        health = health_pb2_grpc.HealthStub(grpc.insecure_channel(s.address))
        checks: list[bool] = []
        end = time.monotonic() + seconds + 5.0  # the writer processes take a while to start
        next_report = time.monotonic() + 10.0
        while time.monotonic() < end:
            if time.monotonic() >= next_report:
                next_report += 10.0
                print(f"    {sum(checks)}/{len(checks)} health checks answered, "
                      f"{end - time.monotonic():.0f} s left", flush=True)  # fmt: skip
            try:
                health.Check(health_pb2.HealthCheckRequest(), timeout=2.0)
                checks.append(True)
            except grpc.RpcError:
                checks.append(False)
            time.sleep(0.1)
        results = [out.get(timeout=120) for _ in procs]
        for p in procs:
            p.join(60)
        rss_end = rss_mib(s.process.pid)
        close.set()
        for call in calls:
            call.cancel()
        s.stop()
    latencies = np.array([x for lat, _ in results for x in lat])
    errors = [e for _, errs in results for e in errs]
    return {
        "inserts answered": len(latencies),
        "inserts failed": len(errors),
        "failure codes": sorted(set(errors)),
        "health answered": sum(checks),
        "health checks": len(checks),
        "p50 ms": 1e3 * float(np.percentile(latencies, 50)) if len(latencies) else float("nan"),
        "p99 ms": 1e3 * float(np.percentile(latencies, 99)) if len(latencies) else float("nan"),
        "rss": (rss_start, rss_end),
    }


# ----------------------------------------------------- 5. a world server's limits


def proc_status(pid: int, key: str) -> int:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    raise RuntimeError(f"no {key}")


def world_server_limits(idle: int = 300, announcing: int = 16) -> dict[str, Any]:
    from actors.minecraft.malmo import protocol as P
    from actors.minecraft.malmo.mission_xml import mission_xml

    def connect(port: int) -> socket.socket:
        s = socket.create_connection(("127.0.0.1", port), timeout=30)
        P.send(s, P.HELLO.encode())
        return s

    cmd = [sys.executable, "-m", "actors.minecraft.cli", "minecraft", "serve", "--port", "0"]
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=root)
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline().decode().rsplit(":", 1)[1])
        threads, rss = proc_status(proc.pid, "Threads"), proc_status(proc.pid, "VmRSS")
        socks = [connect(port) for _ in range(idle)]
        refused = 0
        for s in socks:  # the refused ones get one error message and are closed at once
            s.settimeout(0.5)
            try:
                refused += s.recv(1 << 16)[4:].startswith(b"error: ")
            except TimeoutError:
                pass
        out: dict[str, Any] = {
            "idle refused": refused, "idle threads": proc_status(proc.pid, "Threads") - threads,
            "idle rss": (proc_status(proc.pid, "VmRSS") - rss) / 1024,
        }  # fmt: skip
        for s in socks:
            s.close()
        time.sleep(1.0)
        rss = proc_status(proc.pid, "VmRSS")
        slow = [connect(port) for _ in range(announcing)]
        for s in slow:
            s.sendall((4 << 20).to_bytes(4, "big") + b"<")
        time.sleep(1.0)
        out["announcing rss"] = (proc_status(proc.pid, "VmRSS") - rss) / 1024
        for s in slow:
            s.close()
        peak = proc_status(proc.pid, "VmHWM")
        with connect(port) as s:
            start = time.perf_counter()
            xml = P.mission_init_xml(mission_xml(width=2000, height=2000), "chaos")
            P.send(s, xml.encode(), b"chaos:0:1:1")
            ok, reason = P.unpack_int(P.recv(s)), P.recv(s).decode()
            out["frame reply"] = (ok, reason, 1e3 * (time.perf_counter() - start))
        out["frame peak"] = (proc_status(proc.pid, "VmHWM") - peak) / 1024
        return out
    finally:
        proc.terminate()
        proc.wait(30)


def timed(what: str, run: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    print(f"... {what}", flush=True)
    start = time.perf_counter()
    result = run()
    result["wall s"] = time.perf_counter() - start
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="about a minute (fewer cycles)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    random.seed(args.seed)
    cycles = 5 if args.quick else 24
    load_s = 8.0 if args.quick else 60.0

    kill = timed(f"{cycles} SIGKILL/restart cycles, 4 writers", lambda: kill_restart(cycles))
    drop = timed(
        f"{cycles} connection cuts while inserts wait on the rate limiter, 4 writers",
        lambda: dropped_connections(cycles),
    )
    idle = timed(f"64 idle sample streams + 16 writers for {load_s:.0f} s",
                 lambda: idle_streams(load_s))  # fmt: skip
    world = timed("a world server: 300 idle connections, 16 announcing 4 MiB, a 2000x2000 "
                  "frame", world_server_limits)  # fmt: skip

    print()
    print("| fault | cycles | acked items | lost | doubled | stored, not acked | writer errors |")
    print("|---|---|---|---|---|---|---|")
    for name, r in (("SIGKILL + restart", kill), ("connections cut while waiting", drop)):
        print(
            f"| {name} | {r['cycles']} | {r['acked items']:,} | {r['lost']} | {r['doubled']} "
            f"| {r['stored unacked']} | {r['writer errors']} |"
        )
    print()
    print("| load | inserts answered | inserts failed | health answered | p50 ms | p99 ms |")
    print("|---|---|---|---|---|---|")
    codes = f" ({', '.join(idle['failure codes'])})" if idle["failure codes"] else ""
    print(
        f"| 64 idle sample streams + 16 writers, {load_s:.0f} s | {idle['inserts answered']:,} "
        f"| {idle['inserts failed']}{codes} | {idle['health answered']}/{idle['health checks']} "
        f"| {idle['p50 ms']:.1f} | {idle['p99 ms']:.1f} |"
    )
    print()
    print("targets: 0 lost and 0 doubled; every insert and health check answered, p99 <= 100 ms")
    for name, r in (("connection cuts", drop), ("idle streams + writers", idle)):
        start, end = r["rss"]
        print(
            f"server RSS over {name}: {start:.0f} -> {end:.0f} MiB ({end - start:+.1f} MiB "
            f"in {r['wall s']:.0f} s)"
        )
    ok, reason, ms = world["frame reply"]
    print()
    print(
        f"world server: 300 idle connections -> {world['idle refused']} refused at once, "
        f"+{world['idle threads']} threads, {world['idle rss']:+.1f} MiB RSS; 16 connections "
        f"announcing 4 MiB -> {world['announcing rss']:+.1f} MiB RSS; a 2000x2000 "
        f"VideoProducer -> answered {ok} in {ms:.0f} ms, peak RSS "
        f"{world['frame peak']:+.1f} MiB: {reason}"
    )


if __name__ == "__main__":
    main()
