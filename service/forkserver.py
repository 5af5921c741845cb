"""Starting server processes as forks of one that has already imported them.

A replay server spends about 0.25 s of CPU importing grpc, numpy and its own modules
before it listens, and a world server 0.5 s (numba). A driver that starts many (a run's
shards, a supervisor's restarts, a sweep's runs, a test suite) pays that at every start.
A fork server is one process per driver and module, started on the first request, with
the module imported; each server is a fork of it that runs the module's `main(argv)`, as
`python -m MODULE ARGV...` would, under that command's process title, with its own
environment, working folder and output, listening within a few hundredths of a second of
CPU (`python bench/forked_starts.py`).

The servers are the fork server's children: `ForkedProcess` stands in for
`subprocess.Popen` (pid, poll, wait, send_signal, terminate, kill, returncode), the exit
statuses forwarded by the fork server. A fork server ends when its driver does (its stdin
closes), or at `close_all`; its servers run on, as a Popen child of a dead driver does (a
replay server given `--exit-with-parent DRIVER_PID` stops once the driver has died).

Only on Linux: elsewhere, and with GRAFT_FORK_SERVER=0, `start` runs the command as a
plain child process.
"""

from __future__ import annotations

import atexit
import importlib
import json
import os
import select
import selectors
import signal
import subprocess
import sys
import threading
import traceback
from collections.abc import Callable, Mapping, Sequence
from typing import IO, Any, Optional, Union

Process = Union[subprocess.Popen, "ForkedProcess"]
IMPORT_VARIABLES = ("PYTHONPATH", "PYTHONHOME", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")
"""Environment variables that shape what a process imports and how: a fork server runs
with the starting process's environment and these from the request's. Requests that differ
in them get fork servers of their own; every other variable is the fork's own."""
TITLE_ROOM = "GRAFT_FORK_SERVER_TITLE_ROOM"
"""A fork server's environment variable that is room for its forks' process titles."""
ENABLED = sys.platform.startswith("linux") and os.environ.get("GRAFT_FORK_SERVER") != "0"
"""Whether `start` forks (Linux, unless GRAFT_FORK_SERVER=0) or runs a plain process."""


def start(
    module: str,
    argv: Sequence[str],
    *,
    env: Mapping[str, str],
    output: Optional[str] = None,
    own_stderr: bool = False,
    cwd: Optional[str] = None,
) -> Process:
    """`python -m module *argv` with `env` and `cwd`, its stdout and stderr appended to
    `output` (None: discarded; its stderr goes to this process's with `own_stderr`): a fork
    of `module`'s fork server where `ENABLED`, else a plain child process."""
    if not ENABLED:
        with open(output or os.devnull, "ab") as out:
            return subprocess.Popen(
                [sys.executable, "-m", module, *argv], stdout=out,
                stderr=None if own_stderr else subprocess.STDOUT, env=dict(env), cwd=cwd,
            )  # fmt: skip
    if output is not None:
        open(output, "ab").close()  # there once start returns, as for a plain process
    imports = tuple((name, env.get(name)) for name in IMPORT_VARIABLES)
    request = {"argv": list(argv), "env": dict(env), "output": output, "cwd": cwd,
               "own_stderr": own_stderr}  # fmt: skip
    return _server(module, imports).fork(request)


def close_all() -> None:
    """Ends this process's fork servers (their servers run on, as orphans)."""
    with _LOCK:
        servers = list(_SERVERS.values())
        _SERVERS.clear()
    for server in servers:
        server.close()


class ForkedProcess:
    """A fork server's child, with `subprocess.Popen`'s interface."""

    def __init__(self, pid: int, args: list[str]) -> None:
        self.pid = pid
        self.args = args
        self.returncode: Optional[int] = None
        self._exited = threading.Event()
        try:  # to see it exit should its fork server die first
            self._pidfd: Optional[int] = os.pidfd_open(pid)
        except OSError:  # exited already (its status is on its way), or no pidfds here
            self._pidfd = None  # (a container's seccomp): then -9 at once, if orphaned

    def _exit(self, status: int) -> None:
        if self._exited.is_set():
            return
        self.returncode = status
        self._exited.set()
        if self._pidfd is not None:
            os.close(self._pidfd)

    def _orphaned(self) -> None:
        """Its fork server died, and with it the status it would have reported: waits for
        the process to end, and reports -9 (SIGKILL) as its status, unknown."""
        pidfd = self._pidfd
        if pidfd is None:
            self._exit(-signal.SIGKILL)
            return

        def wait_for_exit() -> None:
            select.select([pidfd], [], [])
            self._exit(-signal.SIGKILL)

        threading.Thread(target=wait_for_exit, name=f"orphan {self.pid}", daemon=True).start()

    def poll(self) -> Optional[int]:
        return self.returncode

    def wait(self, timeout: Optional[float] = None) -> int:
        if not self._exited.wait(timeout):
            raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        assert self.returncode is not None
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.returncode is None:  # not a pid the system may have given another process
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:  # exited; its status is on its way
                pass

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class _ForkServer:
    """The driver's side of one fork server: requests in, pids and exit statuses out."""

    def __init__(self, module: str, imports: tuple[tuple[str, Optional[str]], ...]) -> None:
        self.module = module
        env = {k: v for k, v in os.environ.items() if k not in IMPORT_VARIABLES}
        env.update((name, value) for name, value in imports if value is not None)
        # A fork's title is written over the fork server's command line and environment,
        # and cut where they end: with a small environment, or with SPT_NOENV (set in
        # Ray's workers: titles then keep to the command line), a replay server's title
        # lost its --checkpoint-dir. This variable is room for long titles.
        env.pop("SPT_NOENV", None)
        env[TITLE_ROOM] = " " * 4096
        self.process = subprocess.Popen(
            [sys.executable, "-m", __name__, module],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env,
        )  # fmt: skip
        assert self.process.stdin is not None and self.process.stdout is not None
        self.pid = self.process.pid
        self._requests: IO[bytes] = self.process.stdin
        self._replies = self.process.stdout
        self._lock = threading.Lock()  # one request at a time, answered in order
        self._started: list[ForkedProcess | str] = []  # a fork, or why there is none
        self._answered = threading.Condition()
        self._children: dict[int, ForkedProcess] = {}
        threading.Thread(target=self._read, name=f"fork server {module}", daemon=True).start()

    def alive(self) -> bool:
        return self.process.poll() is None

    def fork(self, request: dict[str, Any]) -> ForkedProcess:
        """A fork running `request` (`start`'s arguments), once the fork server says its pid."""
        with self._lock:
            with self._answered:
                self._requests.write(json.dumps(request).encode() + b"\n")
                self._requests.flush()
                while not self._started and self.alive():
                    self._answered.wait(0.5)
                if not self._started:
                    raise RuntimeError(f"the fork server of {self.module} exited")
                child = self._started.pop(0)
        if isinstance(child, str):
            raise OSError(child)
        return child

    def _read(self) -> None:
        for line in self._replies:
            reply = json.loads(line)
            with self._answered:  # a pid always comes before its exit status
                if "exited" in reply:
                    self._children.pop(reply["exited"])._exit(reply["status"])
                elif "error" in reply:
                    self._started.append(reply["error"])
                else:
                    child = ForkedProcess(reply["pid"], [sys.executable, "-m", self.module])
                    self._children[child.pid] = child
                    self._started.append(child)
                self._answered.notify_all()
        with self._answered:  # the fork server is gone: no status will come
            for child in self._children.values():
                child._orphaned()
            self._children.clear()
            self._answered.notify_all()

    def close(self) -> None:
        """Ends the fork server (closing its stdin) and waits for it."""
        try:
            self._requests.close()
        except OSError:
            pass
        try:
            self.process.wait(10.0)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


_Key = tuple[str, tuple[tuple[str, Optional[str]], ...]]
_LOCK = threading.Lock()
_SERVERS: dict[_Key, _ForkServer] = {}
_OWNER = os.getpid()


def _server(module: str, imports: tuple[tuple[str, Optional[str]], ...]) -> _ForkServer:
    """`module`'s fork server for these import variables, started if there is none or it
    died."""
    global _OWNER
    with _LOCK:
        if os.getpid() != _OWNER:  # a fork of the driver: its servers are not ours
            _SERVERS.clear()
            _OWNER = os.getpid()
        server = _SERVERS.get((module, imports))
        if server is None or not server.alive():
            server = _SERVERS[(module, imports)] = _ForkServer(module, imports)
        return server


atexit.register(close_all)


# The fork server's side: runs as `python -m service.forkserver MODULE`.


def _serve(module: str) -> None:
    """Imports `module` (and runs its `warm_up()`, if it has one), then forks a child per
    request line on stdin until stdin closes, reporting each pid and exit status.

    Ctrl-C in a terminal reaches the whole process group: the servers stop on it, as
    they would as plain processes; the fork server ignores it and ends when its driver
    does."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    loaded = importlib.import_module(module)
    if callable(getattr(loaded, "warm_up", None)):
        loaded.warm_up()
    title: Optional[Callable[[str], None]]
    try:
        from setproctitle import setproctitle as title
    except ImportError:  # a title is cosmetic
        title = None
    wake_read, wake_write = os.pipe()
    os.set_blocking(wake_write, False)
    signal.set_wakeup_fd(wake_write)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # wakes the select below
    selector = selectors.DefaultSelector()
    selector.register(0, selectors.EVENT_READ)
    selector.register(wake_read, selectors.EVENT_READ)
    pending = b""
    while True:
        for key, _ in selector.select():
            if key.fd == wake_read:
                os.read(wake_read, 4096)
                _reap()
                continue
            data = os.read(0, 1 << 16)
            if not data:  # the driver closed us, or died
                return
            pending += data
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                request = json.loads(line)
                try:
                    pid = os.fork()
                except OSError as error:
                    _reply({"error": f"fork: {error}"})
                    continue
                if pid == 0:
                    selector.close()
                    os.close(wake_read)
                    os.close(wake_write)
                    _child(loaded, module, request, title)
                _reply({"pid": pid})


def _reap() -> None:
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        _reply({"exited": pid, "status": os.waitstatus_to_exitcode(status)})


def _reply(message: dict[str, Any]) -> None:
    os.write(1, json.dumps(message).encode() + b"\n")


def _child(
    loaded: Any, module: str, request: dict[str, Any], title: Optional[Callable[[str], None]]
) -> None:
    """In the fork: becomes `python -m module *argv` and never returns."""
    code = 1
    try:
        if title is not None:  # first: it finds the title's memory through the environment
            title(" ".join([sys.executable, "-m", module, *request["argv"]]))
        signal.set_wakeup_fd(-1)
        for sig in (signal.SIGCHLD, signal.SIGTERM, signal.SIGPIPE):
            signal.signal(sig, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.close(null)
        output = request["output"] or os.devnull
        out = os.open(output, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        os.dup2(out, 1)
        if not request["own_stderr"]:  # else the fork server's: its driver's
            os.dup2(out, 2)
        os.close(out)
        os.environ.clear()
        os.environ.update(request["env"])
        if request["cwd"]:
            os.chdir(request["cwd"])
        argv = request["argv"]
        sys.argv = [module, *argv]
        result = loaded.main(argv)
        code = result if isinstance(result, int) else 0
    except SystemExit as stop:
        if stop.code is None or isinstance(stop.code, int):
            code = stop.code or 0
        else:  # as Python does: the message on stderr, status 1
            print(stop.code, file=sys.stderr)
    except KeyboardInterrupt:
        code = 128 + signal.SIGINT
    except BaseException:  # noqa: BLE001 - reported as Python would, then status 1
        traceback.print_exc()
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


if __name__ == "__main__":
    _serve(sys.argv[1])
