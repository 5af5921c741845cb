"""`graft replay serve` and `graft replay info`: run and inspect a replay server."""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path
from typing import Optional

from graft.replay_host.process import EXIT_FOLDER_UNUSABLE
from service.replay.server.writers import DEFAULT_MAX_WRITERS


def add_replay_commands(subparsers: argparse._SubParsersAction) -> None:
    replay = subparsers.add_parser("replay", help="run or inspect a replay server")
    commands = replay.add_subparsers(dest="replay_command", required=True)
    serve = commands.add_parser("serve", help="start a replay server")
    source = serve.add_mutually_exclusive_group()
    source.add_argument("--config", help="YAML/JSON file with a 'tables' list")
    source.add_argument(
        "--preset",
        default="pendulum-td3",
        help="derive the transition table from a training preset (default)",
    )
    serve.add_argument("--host", default="127.0.0.1", help="bind address (default loopback)")
    serve.add_argument("--port", type=int, default=9100)
    _add_token_arguments(serve, "the shared token clients must send")
    serve.add_argument(
        "--insecure", action="store_true", help="allow a non-loopback bind without a token"
    )
    serve.add_argument("--tls-cert", type=Path, help="PEM certificate chain (enables TLS)")
    serve.add_argument("--tls-key", type=Path, help="PEM private key")
    serve.add_argument(
        "--max-message-mb",
        type=float,
        default=64.0,
        help="largest request/response in MiB (default 64)",
    )
    serve.add_argument(
        "--checkpoint-dir",
        type=Path,
        help="durable state: restored on start, write-ahead log, checkpoints",
    )
    serve.add_argument(
        "--checkpoint-every-s",
        type=float,
        default=300.0,
        help="seconds between periodic checkpoints (0 = only on demand/exit)",
    )
    serve.add_argument(
        "--fsync",
        action="store_true",
        help="fsync every logged insert (survives power loss, slower)",
    )
    serve.add_argument(
        "--max-writers",
        type=int,
        default=DEFAULT_MAX_WRITERS,
        help="writers whose last batch number is remembered for exactly-once resends; "
        f"past it the least recently written is forgotten (default {DEFAULT_MAX_WRITERS:,})",
    )
    serve.add_argument(
        "--metrics-port", type=int, help="serve Prometheus metrics on this HTTP port"
    )
    serve.add_argument(
        "--metrics-host",
        default="127.0.0.1",
        help="bind address of the metrics port, which answers without a token (default "
        "loopback, whatever --host is)",
    )
    serve.add_argument(
        "--max-memory",
        type=_byte_size,
        metavar="SIZE",
        help="what the tables may fill together, e.g. 2G or 512M (default: the cgroup's "
        "memory limit, else the machine's memory, less a tenth); a table that cannot fit "
        "is refused at start",
    )
    serve.add_argument("--ready-file", help="write {'address': ...} here once listening")
    serve.add_argument(
        "--exit-with-parent",
        type=int,
        metavar="PID",
        help="stop gracefully (final checkpoint) once process PID, the one that started "
        "this server, has died",
    )
    serve.set_defaults(handler=_serve)
    info = commands.add_parser("info", help="print a server's tables and figures")
    info.add_argument("address", help="host:port")
    _add_token_arguments(info, "the server's shared token")
    info.set_defaults(handler=_info)


def _add_token_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument(
        "--token-file",
        type=Path,
        help=f"file holding {what} (default: the GRAFT_TOKEN environment variable)",
    )
    # Refused with a hint: a command line is readable by every local user (ps, /proc).
    parser.add_argument("--token", dest="token_on_command_line", help=argparse.SUPPRESS)


def _token(args: argparse.Namespace, command: str) -> Optional[str]:
    """The token from --token-file, else from GRAFT_TOKEN; never from the command line."""
    if args.token_on_command_line is not None:
        raise SystemExit(
            f"graft replay {command}: --token would show the secret to every local user in "
            "the process list; set GRAFT_TOKEN or pass --token-file PATH instead"
        )
    if args.token_file is not None:
        try:
            token = args.token_file.read_text().strip()
        except OSError as error:
            raise SystemExit(f"graft replay {command}: --token-file: {error}") from None
        if not token:
            raise SystemExit(f"graft replay {command}: --token-file {args.token_file} is empty")
        return token
    return os.environ.get("GRAFT_TOKEN") or None


def _table_specs(args: argparse.Namespace) -> list[dict]:
    if args.config:
        import yaml  # only here: the launcher's config is JSON, which YAML reads

        with open(args.config) as f:
            data = yaml.safe_load(f)
        if not isinstance(data, dict) or not isinstance(data.get("tables"), list):
            raise SystemExit(f"{args.config}: expected a mapping with a 'tables' list")
        return data["tables"]
    from graft.config import load_preset
    from graft.orchestration.tables import transition_table_spec

    return [transition_table_spec(load_preset(args.preset))]


def warm_up() -> None:
    """Imports what a replay server runs (gRPC, the tables), as the fork server that forks
    `graft train`'s replay servers does before its first fork (service/forkserver.py);
    other `graft` commands never load them."""
    import service.replay.server.serve  # noqa: F401
    import service.replay.server.store  # noqa: F401
    import service.replay.server.table_config  # noqa: F401


def _serve(args: argparse.Namespace) -> None:
    from service.memory import memory_budget
    from service.replay.server.grpc_server import ServerOptions
    from service.replay.server.serve import serve_forever
    from service.replay.server.store import FolderUnusable, ReplayCore
    from service.replay.server.table_config import make_tables

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    try:
        budget = memory_budget(args.max_memory)
        core = ReplayCore(
            make_tables(_table_specs(args), budget=budget),
            checkpoint_dir=args.checkpoint_dir,
            fsync=args.fsync,
            max_writers=args.max_writers,
            memory_budget=budget,
        )
        options = ServerOptions(
            host=args.host,
            port=args.port,
            token=_token(args, "serve"),
            insecure=args.insecure,
            tls_cert=args.tls_cert,
            tls_key=args.tls_key,
            max_message_bytes=int(args.max_message_mb * 2**20),
        )
        serve_forever(
            core,
            options,
            ready_file=args.ready_file,
            metrics_port=args.metrics_port,
            metrics_host=args.metrics_host,
            checkpoint_every_s=args.checkpoint_every_s if args.checkpoint_dir else 0.0,
            parent_pid=args.exit_with_parent,
        )
    except FolderUnusable as error:  # its own status: a launcher may move the folder aside
        print(f"graft replay serve: {error}", file=sys.stderr, flush=True)
        raise SystemExit(EXIT_FOLDER_UNUSABLE) from None
    except (ValueError, OSError) as error:
        raise SystemExit(f"graft replay serve: {error}") from None
    except MemoryError as error:  # past the budget's estimate: still one line
        message = f"graft replay serve: out of memory building the tables: {error}"
        raise SystemExit(message) from None


_SIZE_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def _byte_size(text: str) -> int:
    """``2G``, ``512M``, ``1.5GiB`` or a number of bytes, as bytes (argparse's type)."""
    value = text.strip().upper().removesuffix("IB").removesuffix("B")
    unit = value[-1:] if value[-1:] in _SIZE_UNITS else ""
    try:
        number = float(value.removesuffix(unit) if unit else value)
    except ValueError:
        message = f"{text!r} is not a size like 2G, 512M or 1000000"
        raise argparse.ArgumentTypeError(message) from None
    if not (number > 0 and number * _SIZE_UNITS[unit] < 2**63):
        raise argparse.ArgumentTypeError(f"{text!r} must be a size > 0")
    return int(number * _SIZE_UNITS[unit])


def _info(args: argparse.Namespace) -> None:
    from service.memory import gib
    from service.replay.client import ReplayClient
    from service.replay.errors import ReplayError

    client = ReplayClient(args.address, token=_token(args, "info"), max_retries=0)
    try:
        tables = client.info()
    except ReplayError as error:
        raise SystemExit(f"graft replay info: {error}") from None
    if tables and tables[0].memory_budget_bytes:
        total = sum(t.bytes_in_memory for t in tables)
        print(
            f"memory: tables {gib(sum(t.bytes_used for t in tables))} used, {gib(total)} at "
            f"max_size, of a budget of {gib(tables[0].memory_budget_bytes)} "
            f"({tables[0].memory_budget})"
        )
    for t in tables:
        print(
            f"table {t.name}: {t.size}/{t.max_size} items, {t.inserts} inserted, "
            f"{t.samples} sampled, {gib(t.bytes_used)} used of {gib(t.bytes_in_memory)} "
            "at max_size"
        )
        print(
            f"  sampler={t.sampler} remover={t.remover} rate_limiter={t.rate_limiter} "
            f"blocked={t.rate_limiter_blocked_s:.1f}s"
        )
        print(f"  signature={json.dumps(t.signature)}")


def main(argv: Optional[list[str]] = None) -> None:
    parser = argparse.ArgumentParser(prog="graft")
    add_replay_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["replay", *(argv if argv is not None else sys.argv[1:])])
    args.handler(args)


if __name__ == "__main__":
    main()
