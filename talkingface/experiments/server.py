"""The lab's tracking server: one MLflow server, backed by PostgreSQL, that a group logs to.

Everything lives in one folder (``talkingface server --folder DIR``, default ``./mlflow-server``)::

    DIR/pgdata/      the PostgreSQL cluster (made on the first start, reused after); database
                     ``mlflow``, role ``talkingface``, listening on 127.0.0.1 only
    DIR/artifacts/   the artifact store: clients upload through the server (``mlflow-artifacts:``)
    DIR/logs/        postgres.log, mlflow.log
    DIR/db-password  the database role's password (mode 600, readable by whoever starts the
                     server only), made with the cluster

PostgreSQL refuses to run as root, so a root user runs the cluster as the ``postgres`` system
user that Debian's ``postgresql`` package creates (``DIR/pgdata`` and ``DIR/logs`` are given to
it); anyone else runs it as themselves. The database asks for a password (scram-sha-256) even
on 127.0.0.1, so other users of a shared machine cannot reach it; the server gives the password
to PostgreSQL's programs and to MLflow in their environment (``PGPASSWORD``), never on a command
line. MLflow runs in a process group of its own, so stopping
the server stops its web workers and job runners too: nothing is left running.

Library code: no MLflow import (the server is a separate process); the CLI is
:mod:`talkingface.cli.lab_server`.
"""
from __future__ import annotations

import contextlib
import glob
import importlib.util
import json
import os
import pwd
import re
import secrets
import shutil
import subprocess
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

from groundwork.errors import ParameterError, TalkingFaceError
from talkingface.experiments.mlflow_app import APP_NAME, check_installed
from talkingface.experiments.processes import (check_free, check_port, lan_address, last_lines,
                                               stop_process_group, url_host)

DEFAULT_FOLDER = Path("mlflow-server")
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 5000
# not 5432: that is where a machine's own PostgreSQL (Debian's cluster "main") listens
DEFAULT_DB_PORT = 5433
DB_NAME = "mlflow"
DB_ROLE = "talkingface"
RUN_AS = "postgres"  # the unprivileged user of Debian's postgresql package
SET_UP = "run `make server` or `bash tools/setup.sh server`"
PG_SEARCH = "/usr/lib/postgresql/*/bin"  # Debian's layout: one folder per major version
PG_PROGRAM_TIMEOUT_S = 300  # initdb, pg_ctl (which waits for the server itself), psql, createdb


def postgres_bin(version: str | None = None, *, search: str = PG_SEARCH) -> Path:
    """The folder of PostgreSQL's programs: ``/usr/lib/postgresql/<version>/bin`` (the highest
    version when ``version`` is None; ``search`` is that pattern), else the folder of
    ``initdb`` on ``PATH``.

    Raises
    ------
    TalkingFaceError
        PostgreSQL is not installed, or not the ``version`` an existing cluster needs.
    """
    found = {}
    for d in glob.glob(search):
        if os.access(Path(d) / "initdb", os.X_OK) and os.access(Path(d) / "pg_ctl", os.X_OK):
            found[Path(d).parent.name] = Path(d)
    on_path = shutil.which("initdb")
    if version is not None:
        if version in found:
            return found[version]
        if on_path and _major(Path(on_path)) == version:
            return Path(on_path).parent
        have = ", ".join(sorted(found)) or "none"
        raise TalkingFaceError(f"this database was made by PostgreSQL {version}, but its programs "
                               f"are not installed (PostgreSQL versions found: {have}): install "
                               f"Debian's postgresql-{version}, or start from a new --folder")
    if found:
        return found[max(found, key=lambda v: [int(x) for x in re.findall(r"\d+", v)] or [0])]
    if on_path:
        return Path(on_path).parent
    raise TalkingFaceError(f"PostgreSQL's programs (initdb, pg_ctl) were not found in {search} "
                           f"or on PATH: {SET_UP} to install them")


def _major(initdb: Path) -> str:
    out = subprocess.run([str(initdb), "--version"], capture_output=True, text=True,
                         timeout=PG_PROGRAM_TIMEOUT_S).stdout
    m = re.search(r"(\d+)", out)
    return m.group(1) if m else ""


class LabServer:
    """An MLflow tracking server on PostgreSQL, with its data in ``folder``.

    Parameters
    ----------
    folder : path
        The server's folder (made if missing): ``pgdata/``, ``artifacts/``, ``logs/``.
    host : str
        Address the MLflow server listens on: ``127.0.0.1`` (this machine only), an address
        of this machine on the lab's network, or ``0.0.0.0`` (every interface).
    port : int
        The MLflow server's TCP port.
    db_port : int
        PostgreSQL's TCP port (on 127.0.0.1 only: the database is not on the network).
    start_timeout : float
        Seconds to wait for the server to answer (5-40 s on 2 cores, with the load).
    allowed_hosts : str, optional
        Passed to ``mlflow server --allowed-hosts`` (the names colleagues reach it by, when
        not an IP address; MLflow allows localhost and private IPs by default).
    jobs : bool
        Run MLflow's job runner (its GenAI jobs: LLM judges, prompt optimisation, trace
        archival). Off by default: model training does not use it, and it is ~8 more
        processes and twice the start-up time.
    progress : callable, optional
        Called with a line of text at each step.

    Attributes
    ----------
    uri : str
        The tracking URI on this machine, ``http://127.0.0.1:PORT`` for a server on every
        interface.
    share_uri : str
        The tracking URI to give colleagues (this machine's network address for ``0.0.0.0``).
    created : bool
        Whether the last :meth:`start` made the cluster and the database (the first start).
    """

    def __init__(self, folder, *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 db_port: int = DEFAULT_DB_PORT, start_timeout: float = 300.0,
                 allowed_hosts: str | None = None, jobs: bool = False, progress=None):
        self.folder = Path(folder).absolute()
        self.host, self.port, self.db_port = host, port, db_port
        self.start_timeout = start_timeout
        self.allowed_hosts = allowed_hosts
        self.jobs = jobs
        self.progress = progress or (lambda line: None)
        self.pgdata = self.folder / "pgdata"
        self.artifacts = self.folder / "artifacts"
        self.logs = self.folder / "logs"
        self.created = False
        self._mlflow: subprocess.Popen | None = None
        self._postgres_up = False
        self._bin: Path | None = None
        self._user: pwd.struct_passwd | None = None
        self._password: str | None = None

    @property
    def uri(self) -> str:
        local = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(self.host, self.host)
        return f"http://{url_host(local)}:{self.port}"

    @property
    def share_uri(self) -> str:
        if self.host in ("0.0.0.0", "::"):
            return f"http://{url_host(lan_address())}:{self.port}"
        return self.uri

    @property
    def backend_uri(self) -> str:
        return f"postgresql://{DB_ROLE}@127.0.0.1:{self.db_port}/{DB_NAME}"

    # -- start -------------------------------------------------------------------------------
    def check(self) -> None:
        """Every refusal that needs nothing started: folder, ports, programs, driver, user."""
        if self.folder.exists() and not self.folder.is_dir():
            raise ParameterError(f"--folder {self.folder}: is a file; allowed: a folder (made "
                                 "if missing) for the server's database, artifacts and logs")
        check_port(self.port, "--port")
        check_port(self.db_port, "--db-port")
        if not (isinstance(self.start_timeout, (int, float)) and 0 < self.start_timeout < 1e6):
            raise ParameterError(f"--start-timeout {self.start_timeout}: allowed: a number of "
                                 "seconds > 0")
        if self.port == self.db_port:
            raise ParameterError(f"--port and --db-port are both {self.port}; allowed: two "
                                 "different ports (MLflow's and PostgreSQL's)")
        check_free(self.host, self.port, "--port")
        check_free("127.0.0.1", self.db_port, "--db-port")
        version_file = self.pgdata / "PG_VERSION"
        self._bin = postgres_bin(version_file.read_text().strip()
                                 if version_file.is_file() else None)
        if importlib.util.find_spec("psycopg") is None:
            raise TalkingFaceError("the PostgreSQL driver psycopg (3) is not installed in "
                                   f"{sys.executable}: {SET_UP}")
        if os.geteuid() == 0:
            try:
                self._user = pwd.getpwnam(RUN_AS)
            except KeyError:
                raise TalkingFaceError(f"PostgreSQL refuses to run as root, and the system user "
                                       f"'{RUN_AS}' it would run as does not exist: "
                                       f"{SET_UP}") from None

    def start(self) -> "LabServer":
        """Start PostgreSQL (making the cluster and database on the first start) and the
        MLflow server, and wait until the server answers. Whatever was started is stopped
        again when starting fails or is interrupted."""
        self.check()
        try:
            self._prepare_folder()
            self._start_postgres()
            self._start_mlflow()
            self._wait_until_up()
        except BaseException:
            with contextlib.suppress(TalkingFaceError):  # the first error is the one to tell
                self.stop()
            raise
        return self

    def _prepare_folder(self) -> None:
        for d in (self.folder, self.artifacts, self.logs):
            d.mkdir(parents=True, exist_ok=True)
        if self.pgdata.exists() and any(self.pgdata.iterdir()) and \
                not (self.pgdata / "PG_VERSION").is_file():
            raise TalkingFaceError(f"{self.pgdata} is not empty and not a PostgreSQL cluster "
                                   "(no PG_VERSION): move it away, or choose another --folder")
        self.pgdata.mkdir(mode=0o700, exist_ok=True)
        if self._user is not None:
            uid, gid = self._user.pw_uid, self._user.pw_gid
            reach = subprocess.run(["test", "-x", str(self.folder)], user=uid, group=gid,
                                   extra_groups=[], timeout=PG_PROGRAM_TIMEOUT_S)
            if reach.returncode != 0:
                raise TalkingFaceError(
                    f"--folder {self.folder}: the '{RUN_AS}' user that runs PostgreSQL (it "
                    "refuses root) cannot enter it, as a folder above it is closed to other "
                    "users (e.g. /root, mode 700): choose a folder under one others may "
                    "enter, e.g. /srv/mlflow-server")
            # a folder restored from a backup may belong to another uid: give it back
            for d in (self.pgdata, self.logs):
                if d.stat().st_uid != uid:
                    for p in [d, *d.rglob("*")]:
                        os.chown(p, uid, gid, follow_symlinks=False)
        os.chmod(self.pgdata, 0o700)

    def _pg(self, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        """A PostgreSQL program, as the ``postgres`` user when we are root."""
        kw = {}
        if self._user is not None:
            kw = dict(user=self._user.pw_uid, group=self._user.pw_gid, extra_groups=[])
        env = {**os.environ, "LC_ALL": "C.UTF-8", **self._password_env()}
        try:
            done = subprocess.run([str(self._bin / args[0]), *args[1:]], cwd=self.logs, env=env,
                                  stdin=subprocess.DEVNULL, capture_output=True, text=True,
                                  start_new_session=True, timeout=PG_PROGRAM_TIMEOUT_S, **kw)
        except subprocess.TimeoutExpired:
            raise TalkingFaceError(f"PostgreSQL's {args[0]} did not finish within "
                                   f"{PG_PROGRAM_TIMEOUT_S} s for {self.pgdata}; see the logs in "
                                   f"{self.logs}") from None
        if check and done.returncode != 0:
            out = " | ".join(x for x in (done.stdout + done.stderr).splitlines() if x.strip())
            raise TalkingFaceError(f"PostgreSQL's {args[0]} failed (exit status "
                                   f"{done.returncode}) for {self.pgdata}: {out[-600:]}")
        return done

    @property
    def _password_file(self) -> Path:
        return self.folder / "db-password"

    def _new_password(self) -> None:
        """A new random password for the database role, kept in ``DIR/db-password`` (mode
        600)."""
        self._password = secrets.token_urlsafe(24)
        self._password_file.unlink(missing_ok=True)
        fd = os.open(self._password_file, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(self._password + "\n")

    def _password_env(self) -> dict:
        """``PGPASSWORD`` for PostgreSQL's programs and MLflow (libpq reads it); empty for a
        cluster without a password file."""
        if self._password is None and self._password_file.is_file():
            self._password = self._password_file.read_text().strip()
        return {"PGPASSWORD": self._password} if self._password else {}

    def _start_postgres(self) -> None:
        self.created = not (self.pgdata / "PG_VERSION").is_file()
        if self.created:
            self.progress(f"making the PostgreSQL cluster {self.pgdata}")
            self._new_password()
            pwfile = self.logs / ".initdb-password"  # for initdb alone, removed after it
            try:
                fd = os.open(pwfile, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
                with os.fdopen(fd, "w") as f:
                    f.write(self._password + "\n")
                if self._user is not None:
                    os.chown(pwfile, self._user.pw_uid, self._user.pw_gid)
                self._pg("initdb", "-D", str(self.pgdata), "-A", "scram-sha-256",
                         f"--pwfile={pwfile}", "-U", DB_ROLE, "-E", "UTF8", "--locale=C")
            finally:
                pwfile.unlink(missing_ok=True)
        elif self._pg("pg_ctl", "-D", str(self.pgdata), "status", check=False).returncode == 0:
            # never start (nor, on failure, stop) the PostgreSQL of another running server
            raise TalkingFaceError(f"--folder {self.folder}: its PostgreSQL is already running "
                                   "(is another `talkingface server` using this folder?): stop "
                                   "that one first, or choose another --folder")
        else:
            warn_trusting(self.pgdata)
        log = self.logs / "postgres.log"
        opts = (f"-p {self.db_port} -c listen_addresses=127.0.0.1 "
                "-c unix_socket_directories=''")
        self._postgres_up = True  # from here on, stop() runs pg_ctl stop
        started = self._pg("pg_ctl", "-D", str(self.pgdata), "-l", str(log), "-o", opts,
                           "-w", "-t", "120", "start", check=False)
        if started.returncode != 0:
            raise TalkingFaceError(f"PostgreSQL did not start on 127.0.0.1:{self.db_port} (data "
                                   f"{self.pgdata}); the last lines of its log {log}: "
                                   f"{last_lines(log)}")
        have = self._pg("psql", "-X", "-q", "-h", "127.0.0.1", "-p", str(self.db_port),
                        "-U", DB_ROLE, "-d", "postgres", "-tAc",
                        f"SELECT 1 FROM pg_database WHERE datname = '{DB_NAME}'")
        if have.stdout.strip() != "1":
            self.progress(f"making the database {DB_NAME}")
            self._pg("createdb", "-h", "127.0.0.1", "-p", str(self.db_port), "-U", DB_ROLE,
                     DB_NAME)
            self.created = True

    def _start_mlflow(self) -> None:
        check_installed()  # the app below is registered in this environment
        # this project's app: MLflow's, opening experiments on their runs table in a browser
        # that has not chosen MLflow's GenAI view (talkingface/experiments/mlflow_app.py)
        cmd = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri",
               self.backend_uri, "--artifacts-destination", str(self.artifacts),
               "--host", self.host, "--port", str(self.port), "--workers", "1",
               "--app-name", APP_NAME]
        if self.allowed_hosts:
            # MLflow matches the Host header, port included ("name:5000" from a browser), and
            # accepts only the names listed once any are (its defaults, localhost and private
            # addresses, are dropped): a bare name is given with this port too, and the
            # addresses this server is reached by on this machine (its own wait and look-ups)
            # and the one it gives colleagues are added
            names = []
            for h in filter(None, (h.strip() for h in self.allowed_hosts.split(","))):
                bare = ":" not in h and "*" not in h
                names += [h, f"{h}:{self.port}"] if bare else [h]
            own = [urllib.parse.urlsplit(u).netloc for u in (self.uri, self.share_uri)]
            cmd += ["--allowed-hosts",
                    ",".join(dict.fromkeys([*names, *own, f"localhost:{self.port}"]))]
        self.progress(f"starting the MLflow server on {self.uri} (up to a minute)")
        env = {**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": str(self.jobs).lower(),
               **self._password_env()}
        with open(self.logs / "mlflow.log", "ab") as log:
            self._mlflow = subprocess.Popen(cmd, cwd=self.folder, env=env,
                                            stdin=subprocess.DEVNULL, stdout=log,
                                            stderr=subprocess.STDOUT, start_new_session=True)

    def _wait_until_up(self) -> None:
        """Poll the REST API (which reads the database) until it answers 200."""
        url = f"{self.uri}/api/2.0/mlflow/experiments/search?max_results=1"
        log = self.logs / "mlflow.log"
        deadline = time.monotonic() + self.start_timeout
        while True:
            code = self._mlflow.poll()
            if code is not None:
                raise TalkingFaceError(f"the MLflow server exited (status {code}) before it "
                                       f"answered; the last lines of its log {log}: "
                                       f"{last_lines(log)}")
            try:
                with urllib.request.urlopen(url, timeout=5) as r:
                    if r.status == 200 and "experiments" in json.loads(r.read() or b"{}"):
                        return
            except (OSError, ValueError):
                pass
            if time.monotonic() > deadline:
                raise TalkingFaceError(f"the MLflow server did not answer on {self.uri} within "
                                       f"{self.start_timeout:g} s; the last lines of its log "
                                       f"{log}: {last_lines(log)}")
            time.sleep(0.5)

    # -- run and stop ------------------------------------------------------------------------
    def wait(self) -> int:
        """Block until the MLflow server exits by itself; its exit status."""
        return self._mlflow.wait()

    def stop(self) -> None:
        """Stop the MLflow server (its whole process group) and PostgreSQL, and wait for
        both. Safe to call twice."""
        if self._mlflow is not None:
            stop_process_group(self._mlflow)
            self._mlflow = None
        if self._postgres_up:
            self._postgres_up = False
            if (self.pgdata / "postmaster.pid").exists():
                self._pg("pg_ctl", "-D", str(self.pgdata), "-m", "fast", "-w", "-t", "120",
                         "stop", check=False)
            if (self.pgdata / "postmaster.pid").exists():
                log = self.logs / "postgres.log"
                raise TalkingFaceError(f"PostgreSQL of {self.pgdata} did not stop (pg_ctl stop "
                                       f"-m fast); the last lines of its log {log}: "
                                       f"{last_lines(log)}")

    def __enter__(self) -> "LabServer":
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.stop()
        except TalkingFaceError:
            if exc_type is None:  # else the error that left the block is the one to tell
                raise


def warn_trusting(pgdata: Path) -> bool:
    """Warn when ``pgdata``'s ``pg_hba.conf`` trusts users (no password); True if it warned."""
    hba = Path(pgdata) / "pg_hba.conf"
    try:
        lines = hba.read_text(errors="replace").splitlines()
    except OSError:  # missing or unreadable: nothing seen to warn about
        return False
    if not any(w[-1] == "trust" for w in (line.split("#")[0].split() for line in lines) if w):
        return False
    print(f"warning: {hba} lets every user of this machine into the database without a "
          "password (made by an older `talkingface server`): set a password for the role and "
          "replace 'trust' by 'scram-sha-256' there, or start a new --folder", file=sys.stderr)
    return True


@contextlib.contextmanager
def lab_server(folder=DEFAULT_FOLDER, *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
               db_port: int = DEFAULT_DB_PORT, **kw):
    """``with lab_server(folder, port=..., db_port=...) as server:`` a started
    :class:`LabServer` (``server.uri``), stopped on leaving, whatever happened."""
    server = LabServer(folder, host=host, port=port, db_port=db_port, **kw)
    server.start()
    try:
        yield server
    finally:
        server.stop()
