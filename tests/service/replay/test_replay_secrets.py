"""Secrets and exposure of a replay server process: the token, the metrics port, IPv6, TLS.

Loopback only: 127.0.0.2 stands for "an address other than 127.0.0.1" (all of 127/8 is
the loopback interface on Linux).
"""

from __future__ import annotations

import subprocess
import sys
import urllib.error
import urllib.request

import pytest

from graft.replay_host.process import ReplayProcess
from service.replay.client import ReplayClient
from service.replay.errors import Unauthenticated, Unavailable
from tests.service.replay.helpers import SCALAR_SIGNATURE, free_port, scalar_batch, self_signed_cert

pytestmark = pytest.mark.service  # real server processes, or Ray

TABLE = [{"name": "t", "max_size": 100, "signature": SCALAR_SIGNATURE}]
TOKEN = "graft-test-secret-3f9c1d"


def _command_line(pid: int) -> str:
    with open(f"/proc/{pid}/cmdline", "rb") as f:
        return f.read().replace(b"\0", b" ").decode()


def test_launcher_keeps_the_token_off_the_command_line():
    """Any local user can read a process's command line; the token goes by environment."""
    with ReplayProcess(TABLE, token=TOKEN) as server:
        assert TOKEN not in _command_line(server.process.pid)
        assert ReplayClient(server.address, token=TOKEN).insert("t", scalar_batch(range(3))) == 3
        with pytest.raises(Unauthenticated):
            ReplayClient(server.address, max_retries=0).info()


def test_serve_reads_the_token_from_a_file(tmp_path):
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    with ReplayProcess(TABLE, extra_args=["--token-file", str(token_file)]) as server:
        assert TOKEN not in _command_line(server.process.pid)
        assert ReplayClient(server.address, token=TOKEN).insert("t", scalar_batch(range(3))) == 3
        with pytest.raises(Unauthenticated):
            ReplayClient(server.address, token="wrong", max_retries=0).info()


def test_a_token_on_the_command_line_is_refused():
    result = subprocess.run(
        [sys.executable, "-m", "graft.cli.replay", "serve", "--port", "0", "--token", TOKEN],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode != 0
    assert "GRAFT_TOKEN" in result.stderr and "--token-file" in result.stderr


def _answers(url: str) -> bool:
    try:
        urllib.request.urlopen(url, timeout=10).read()
        return True
    except (urllib.error.URLError, ConnectionError):
        return False


def test_metrics_bind_loopback_unless_told_otherwise():
    """The gRPC port is on 127.0.0.2 (not "loopback" to the server: it needs the token);
    the unauthenticated metrics endpoint stays on 127.0.0.1 unless --metrics-host says."""
    port = free_port()
    with ReplayProcess(
        TABLE, host="127.0.0.2", token=TOKEN, extra_args=["--metrics-port", str(port)]
    ) as server:
        assert server.address.startswith("127.0.0.2:")
        assert _answers(f"http://127.0.0.1:{port}/metrics")
        assert not _answers(f"http://127.0.0.2:{port}/metrics")
    port = free_port()
    with ReplayProcess(
        TABLE, extra_args=["--metrics-port", str(port), "--metrics-host", "127.0.0.2"]
    ):
        assert _answers(f"http://127.0.0.2:{port}/metrics")


def test_ipv6_loopback_host():
    with ReplayProcess(TABLE, host="::1") as server:
        assert server.address.startswith("[::1]:")
        client = ReplayClient(server.address)
        client.wait_until_ready(timeout=30)
        assert client.insert("t", scalar_batch(range(4))) == 4
        assert client.sample("t", 2, timeout=10)["x"].shape == (2,)


def test_wait_until_ready_honours_the_token():
    with ReplayProcess(TABLE, token=TOKEN) as server:
        ReplayClient(server.address, token=TOKEN).wait_until_ready(timeout=30)
        with pytest.raises(Unauthenticated):
            ReplayClient(server.address, token="wrong").wait_until_ready(timeout=30)


@pytest.mark.serial  # a plaintext client's wait runs out
def test_wait_until_ready_honours_tls(tmp_path):
    cert, key = self_signed_cert(tmp_path)
    with ReplayProcess(TABLE, extra_args=["--tls-cert", str(cert), "--tls-key", str(key)]) as s:
        ReplayClient(s.address, tls_root_cert=str(cert)).wait_until_ready(timeout=10)
        with pytest.raises(Unavailable):
            ReplayClient(s.address).wait_until_ready(timeout=2)  # plaintext never gets through


def test_a_launcher_without_a_token_gives_its_server_none(monkeypatch):
    """GRAFT_TOKEN in the launcher's own environment must not lock out its token-less client."""
    monkeypatch.setenv("GRAFT_TOKEN", TOKEN)
    with ReplayProcess(TABLE) as server:
        assert ReplayClient(server.address).insert("t", scalar_batch(range(2))) == 2
