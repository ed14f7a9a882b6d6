"""A real two-node Ray cluster on this machine, for the sweep tests: a head and a second node as
separate ``ray start`` processes, every address a loopback one, stopped afterwards.

Ray turns ``--node-ip-address 127.0.0.1`` into the host's outward address once multi-node mode is
on, so the nodes take 127.0.0.2 and 127.0.0.3 (also loopback on Linux: all of 127/8 is routed to
``lo``). Each ``ray start`` runs in a new session, and every process it leaves behind stays in that
session (Ray renames its processes and overwrites their environment, so neither tells);
teardown kills exactly the processes of those sessions (``ray stop`` would stop every Ray on the
machine).
"""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

HEAD_IP = "127.0.0.2"
NODE_IP = "127.0.0.3"
NODE_MARK = "TD_TEST_RAY_NODE"
"""Environment variable every process of the second node inherits (``second``)."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind((HEAD_IP, 0))
        return s.getsockname()[1]


def ray_bin() -> str:
    return str(Path(os.sys.executable).with_name("ray"))


def processes_with(text: str) -> list[int]:
    """PIDs whose command line contains ``text``."""
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if text.encode() in (d / "cmdline").read_bytes():
                    pids.append(int(d.name))
            except OSError:
                pass
    return [p for p in pids if p != os.getpid()]


def environ_of(pid: int) -> dict[str, str]:
    try:
        raw = Path(f"/proc/{pid}/environ").read_bytes()
    except OSError:
        return {}
    return dict(kv.split("=", 1) for kv in raw.decode(errors="replace").split("\0") if "=" in kv)


def _all_pids() -> list[int]:
    return [int(d.name) for d in Path("/proc").iterdir() if d.name.isdigit()]


def _session_of(pid: int) -> int | None:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2 :].split()  # after "pid (name) ": state ppid pgrp session ...
    return None if fields[0] == "Z" else int(fields[3])


class LocalRayCluster:
    def __init__(self, cpus_per_node: int = 1) -> None:
        self.cpus = cpus_per_node
        self.temp = Path(tempfile.mkdtemp(prefix="tdray", dir="/tmp"))  # short: Ray's socket paths
        self.port = _free_port()
        self.sessions: set[int] = set()
        self.address = f"{HEAD_IP}:{self.port}"
        # Ray's token authentication, with a token of this cluster's own (not the user's ~/.ray one):
        # every process that joins or drives it gets ``env``
        self.env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "token",
                    "RAY_AUTH_TOKEN": secrets.token_hex(32)}  # fmt: skip

    def _start(self, *args: str, env: dict[str, str]) -> None:
        proc = subprocess.Popen(
            [ray_bin(), "start", *args, "--num-cpus", str(self.cpus), "--disable-usage-stats"],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
        )  # fmt: skip
        self.sessions.add(proc.pid)
        out, _ = proc.communicate(timeout=180)
        if proc.returncode != 0:
            raise RuntimeError(f"ray start {' '.join(args)} failed:\n{out}")

    def __enter__(self) -> LocalRayCluster:
        try:
            self._start("--head", "--node-ip-address", HEAD_IP, "--port", str(self.port),
                        "--include-dashboard", "false", "--temp-dir", str(self.temp), env=self.env)  # fmt: skip
            self._start("--address", self.address, "--node-ip-address", NODE_IP,
                        env={**self.env, NODE_MARK: "second"})  # fmt: skip
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def pids(self) -> list[int]:
        """The cluster's live processes: those in the sessions of its ``ray start`` calls."""
        return [pid for pid in _all_pids() if _session_of(pid) in self.sessions and pid != os.getpid()]

    def stop(self) -> None:
        for sig in (signal.SIGTERM, signal.SIGKILL):
            for pid in self.pids():
                try:
                    os.kill(pid, sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + 10
            while self.pids() and time.monotonic() < deadline:
                time.sleep(0.2)
        shutil.rmtree(self.temp, ignore_errors=True)
