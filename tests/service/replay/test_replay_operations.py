"""Operating a replay server: TLS, Prometheus metrics, health, and `graft replay info`."""

from __future__ import annotations

import subprocess
import sys
import urllib.request

import grpc
import pytest
from grpc_health.v1 import health_pb2, health_pb2_grpc

from graft.replay_host.process import ReplayProcess
from service.replay.client import ReplayClient
from service.replay.errors import Unavailable
from tests.service.replay.helpers import SCALAR_SIGNATURE, free_port, scalar_batch, self_signed_cert

pytestmark = pytest.mark.service  # real server processes, or Ray

TABLE = [{"name": "t", "max_size": 100, "signature": SCALAR_SIGNATURE}]


def test_tls_server_serves_tls_clients_only(tmp_path):
    cert, key = self_signed_cert(tmp_path)
    with ReplayProcess(TABLE, extra_args=["--tls-cert", str(cert), "--tls-key", str(key)]) as s:
        secure = ReplayClient(s.address, tls_root_cert=str(cert))
        assert secure.insert("t", scalar_batch(range(5))) == 5
        plain = ReplayClient(s.address, max_retries=0)
        with pytest.raises(Unavailable):
            plain.info()


def test_metrics_health_and_info_command():
    port = free_port()
    with ReplayProcess(TABLE, extra_args=["--metrics-port", str(port)]) as server:
        client = ReplayClient(server.address)
        client.insert("t", scalar_batch(range(7)))
        client.sample("t", 3)
        text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read()
        text = text.decode()
        assert 'graft_replay_table_size{table="t"} 7.0' in text
        assert 'graft_replay_table_samples{table="t"} 3.0' in text
        assert 'graft_replay_rpc_seconds_count{method="Insert"} 1.0' in text
        assert "graft_replay_bytes_in_total" in text

        channel = grpc.insecure_channel(server.address)
        status = health_pb2_grpc.HealthStub(channel).Check(
            health_pb2.HealthCheckRequest(service="graft.replay.v1.ReplayService")
        )
        assert status.status == health_pb2.HealthCheckResponse.SERVING

        shown = subprocess.run(
            [sys.executable, "-m", "graft.cli", "replay", "info", server.address],
            capture_output=True, text=True, timeout=60, check=True,
        ).stdout  # fmt: skip
        assert "table t: 7/100 items, 7 inserted, 3 sampled" in shown
