"""Ports, hosts and process groups of the servers the commands start (``talkingface server``
and ``ui``): a port checked free before a server is started on it, a process group stopped
whole, a log's last lines for a refusal."""
from __future__ import annotations

import contextlib
import errno
import glob
import os
import signal
import socket
import subprocess
import time
from pathlib import Path

from groundwork.errors import ParameterError, TalkingFaceError


def check_port(port: int, option: str = "--port") -> None:
    """Refuse a TCP port outside 1..65535, naming the option and the value."""
    if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
        raise ParameterError(f"{option} {port}: allowed: a TCP port from 1 to 65535")


def check_free(host: str, port: int, option: str = "--port") -> None:
    """Refuse a port something already listens on (checked by binding it, as a server would,
    with ``SO_REUSEADDR``), or a host that is no address of this machine."""
    check_port(port, option)
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise ParameterError(f"--host {host}: unknown ({exc.strerror}); allowed: 127.0.0.1 (this "
                             "machine only), an address of this machine, or 0.0.0.0 (all)")
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise TalkingFaceError(
                    f"{option} {port}: port {port} on {host} is already in use (another server, "
                    f"perhaps a `talkingface server` or `ui` already running): stop it, or "
                    f"choose a free port with {option}") from None
            if exc.errno in (errno.EACCES, errno.EPERM):
                raise TalkingFaceError(f"{option} {port}: not allowed to listen on port {port} "
                                       f"(ports below 1024 need root): choose one above "
                                       f"1023 with {option}") from None
            raise ParameterError(f"--host {host}: cannot listen there ({exc.strerror}); allowed: "
                                 "127.0.0.1 (this machine only), an address of this machine, "
                                 "or 0.0.0.0 (all)") from None


def last_lines(path: Path, n: int = 5) -> str:
    """The last ``n`` non-empty lines of a log, joined into one line."""
    try:
        lines = [x.strip() for x in path.read_text(errors="replace").splitlines() if x.strip()]
    except OSError:
        return "(no log)"
    return " | ".join(lines[-n:]) or "(empty)"


def group_members(pgid: int) -> list[int]:
    """Processes of process group ``pgid`` that still run (zombies are finished: not counted)."""
    out = []
    for stat in glob.glob("/proc/[0-9]*/stat"):
        try:
            text = Path(stat).read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2:].split()  # after "pid (comm) "
        if int(fields[2]) == pgid and fields[0] != "Z":
            out.append(int(Path(stat).parent.name))
    return out


def stop_process_group(proc: subprocess.Popen, timeout: float = 60.0) -> None:
    """SIGTERM to the whole process group led by ``proc`` (started with
    ``start_new_session=True``), wait for all of it, and SIGKILL what is left after
    ``timeout`` seconds."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    deadline = time.monotonic() + timeout
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=timeout)
    while group_members(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    if group_members(proc.pid) or proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def lan_address() -> str:
    """This machine's address on its network (the one its default route leaves from: a UDP
    socket's connect sends nothing), else its host name."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("10.255.255.255", 1))
            return s.getsockname()[0]
        except OSError:
            return socket.gethostname()
