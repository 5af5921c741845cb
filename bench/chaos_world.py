"""The chaos benchmark's Minecraft part: a world server (``minecraft serve``, default limits)
under idle connections, connections announcing a 4 MiB message, and a 2000x2000 frame.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from procfs import proc_status  # bench/, beside this script


def world_server_limits(idle: int = 300, announcing: int = 16) -> dict[str, Any]:
    """Threads and RSS a world server spends on `idle` idle connections, on `announcing`
    connections that announce 4 MiB and send 1 byte, and its reply to a 2000x2000 frame."""
    from minecraft.malmo import protocol as P
    from minecraft.malmo.mission_xml import mission_xml

    def connect(port: int) -> socket.socket:
        s = socket.create_connection(("127.0.0.1", port), timeout=30)
        P.send(s, P.HELLO.encode())
        return s

    cmd = [sys.executable, "-m", "minecraft.cli", "minecraft", "serve", "--port", "0"]
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
            reason = P.recv(s).decode()  # one `error: ...` message in place of the ok int
            out["frame reply"] = (0, reason, 1e3 * (time.perf_counter() - start))
        out["frame peak"] = (proc_status(proc.pid, "VmHWM") - peak) / 1024
        return out
    finally:
        proc.terminate()
        proc.wait(30)
