"""Dask imports and clients: a LocalCluster on loopback, or an existing scheduler."""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import signal
import threading
from collections.abc import Iterator
from typing import Any

from ..core.errors import QuashError
from ..core.optional import require

log = logging.getLogger(__name__)

INSTALL_HINT = 'Install the Dask extra: pip install "quash-plugins[dask]".'


def require_dask() -> Any:
    """Import ``dask.array``, or raise a :class:`QuashError` naming the extra to install."""
    return require("dask.array", "dask", "The dask backend")


def require_zarr() -> Any:
    """Import ``zarr``, or raise a :class:`QuashError` naming the extra to install."""
    return require("zarr", "dask", "Writing results to zarr")


def _require_distributed() -> Any:
    try:
        import distributed
    except ImportError as exc:  # pragma: no cover
        raise QuashError(f"--backend dask needs dask.distributed ({exc}). {INSTALL_HINT}") from None
    return distributed


def machine_cores() -> int:
    """CPU cores this process may use (respects affinity masks and cgroup pinning)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def local_cluster_security() -> Any:
    """A ``distributed.Security`` with a certificate made for this process only (mutual
    TLS), or None, with a warning, when ``cryptography`` is not installed.

    A LocalCluster listens on 127.0.0.1, which every user of the machine can reach, and
    a Dask scheduler runs whatever a client sends it: over plain TCP, anyone logged in
    on a shared machine could run code as you in its workers. With this, a client must
    show the certificate, which never leaves the process's memory and its workers.
    """
    from distributed.security import Security

    try:
        return Security.temporary()
    except ImportError:
        from ..core.once import first_time

        if first_time(("dask-plain-tcp",)):
            log.warning(
                "the local Dask cluster listens on 127.0.0.1 without TLS (cryptography is not "
                "installed): on a shared machine, any user of it could run code in its workers "
                'as you. Install the Dask extra again (pip install "quash-plugins[dask]") '
                "or run with --backend numpy."
            )
        return None


#: The prefix of every task key the pipeline submits (``quash-scores-<token>``...).
TASK_PREFIX = "quash-"


class _OwnComputeFailures(logging.Filter):
    """Drops a worker's "Compute Failed" record of a quash task: the client re-raises
    its exception as one line naming the file and the fix, so the worker's copy (a
    repr of the task and the traceback, at ERROR, which --quiet cannot hide) only
    repeats it as noise. Other tasks' failures and every other record pass."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not str(record.msg).startswith("Compute Failed"):
            return True
        args = record.args if isinstance(record.args, tuple) else ()
        return not (args and TASK_PREFIX in repr(args[0]))


#: The loggers of the scheduler and the nannies of quash's own LocalCluster, which run
#: in the process that started it.
RESTART_LOGGERS = ("distributed.scheduler", "distributed.nanny")


class _OwnWorkerRestarts(logging.Filter):
    """Replaces Dask's records of a worker of quash's own LocalCluster that stopped (the
    scheduler's "Removing worker ... caused the cluster to lose already computed
    task(s) ..." with every task key, the nanny's "Restarting worker", "Worker process
    ... was killed") with one warning of quash's: Dask recomputes the chunks, the
    result is unchanged (a map held in memory, scattered to the workers, is the
    exception: its lost chunks fail the query, which sends it again when run again),
    and the user needs to know only that and what to do if it repeats. Errors (a cluster that gives up) pass."""

    PREFIXES = ("Removing worker", "Restarting worker", "Worker process")

    def __init__(self) -> None:
        super().__init__()
        self.said = False

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.ERROR or not str(record.msg).startswith(self.PREFIXES):
            return True
        if not self.said:
            self.said = True
            log.warning(
                "A worker process of the local Dask cluster stopped (killed, or over its "
                "memory limit); Dask restarts it and computes its chunks again, so the "
                "result is unchanged, except for a map held in memory (an NPZ map), "
                "whose chunks that worker held are lost: that query then fails with a "
                "ClusterError, and running it again sends the map to the workers again. "
                "If it repeats, lower chunk_mb or give fewer --workers (docs/scale.md, "
                "Memory sizing)."
            )
        return False


def quiet_compute_failures() -> None:
    """Install :class:`_OwnComputeFailures` on ``distributed.worker`` in this process
    (run on each worker of a LocalCluster quash started; idempotent)."""
    logger = logging.getLogger("distributed.worker")
    if not any(isinstance(f, _OwnComputeFailures) for f in logger.filters):
        logger.addFilter(_OwnComputeFailures())


def _close_quietly(*closables: Any) -> None:
    """Close each of ``closables`` (a Dask client or cluster), saying nothing if it fails:
    the command is stopping for another reason, the one the user is told."""
    for c in closables:
        if c is not None:
            with contextlib.suppress(Exception):
                c.close()


#: How long Ctrl-C raised from ``Thread.start`` waits for the start thread to run (it
#: always does unless Ctrl-C came before the thread was made; it closes what it starts
#: itself once the caller has given up, so this only bounds the wait).
START_BEGAN_S = 5.0


def _start_without_sigint(start: Any, **kwargs: Any) -> Any:
    """``start(**kwargs)`` (a ``LocalCluster``) from a thread that blocks SIGINT.

    Every thread the cluster starts, and every worker process, inherits that mask, so
    Ctrl-C, which a terminal sends to the whole process group, reaches only this
    process: no worker prints a traceback of its own, and none dies while Dask starts or
    stops it. Here Ctrl-C (or SIGTERM) while the cluster starts waits for the start to
    end, closes the cluster, and is raised again: the ``quash`` command then prints one
    line ("interrupted", exit status 130), and no worker process is left running. A
    second Ctrl-C stops the wait; the start thread then closes the cluster itself once
    its start ends. Without ``pthread_sigmask`` (Windows) the start runs here as it is.
    """
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - not POSIX
        return start(**kwargs)
    outcome: dict[str, Any] = {}
    done = threading.Event()
    given_up = threading.Event()  # the caller was interrupted: nobody takes the cluster
    handover = threading.Lock()  # exactly one of the two closes it
    began = threading.Event()

    def run() -> None:
        began.set()
        # multiprocessing starts its resource tracker with SIGINT blocked, then unblocks
        # it in the calling thread, whatever the mask was: started first, it does not
        # undo the mask when the first worker process is started.
        from multiprocessing import resource_tracker

        try:
            with contextlib.suppress(Exception):
                resource_tracker.ensure_running()
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            value = start(**kwargs)
            with handover:
                outcome["value"] = value
                abandoned = given_up.is_set()
            if abandoned:  # a second Ctrl-C stopped the caller's wait: close it here
                log.debug("the local Dask cluster started after the command gave up: closing it")
                _close_quietly(value)
        except BaseException as exc:  # noqa: BLE001 - raised again in the caller
            outcome["error"] = exc
        finally:
            done.set()

    thread = threading.Thread(target=run, name="quash: local Dask cluster start", daemon=True)
    try:
        thread.start()  # Ctrl-C may be raised from it too (and the thread run all the same)
        # Event.wait, not Thread.join: a join interrupted by Ctrl-C marks the thread
        # stopped (CPython), and the wait below would not wait
        done.wait()
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM (the CLI's Terminated)
        try:
            log.debug("interrupted while the local Dask cluster starts: closing it")
            if began.wait(START_BEGAN_S):  # else no thread ran: nothing was started
                done.wait()
        finally:  # the cluster if it has started, else the start thread closes it
            with handover:
                given_up.set()
                value = outcome.pop("value", None)
            _close_quietly(value)
        raise
    if "error" in outcome:
        raise outcome["error"]
    return outcome["value"]


def local_cluster_client(
    n_workers: int | None = None, threads_per_worker: int = 1, memory_limit: Any = "auto"
) -> Any:
    """Start a ``LocalCluster`` of worker processes on 127.0.0.1 and return its ``Client``.

    Parameters
    ----------
    n_workers
        Worker processes; default one per usable core.
    threads_per_worker
        Threads per worker process. One keeps a single chunk in flight per worker.
    memory_limit
        Per-worker limit (``"2GiB"``); ``"auto"`` shares the machine's memory evenly.
    """
    distributed = _require_distributed()
    n = int(n_workers or machine_cores())
    security = local_cluster_security()
    cluster = _start_without_sigint(
        distributed.LocalCluster,
        n_workers=n,
        threads_per_worker=threads_per_worker,
        processes=True,
        host="127.0.0.1",
        # its web server (health and metrics; the dashboard where bokeh is installed) on
        # loopback too, on a free port: a dashboard already on 8787 is left alone
        dashboard_address="127.0.0.1:0",
        memory_limit=memory_limit,
        security=security,
    )
    client = None
    try:
        client = distributed.Client(cluster, security=security)
        if not logging.getLogger("quash_plugins").isEnabledFor(logging.DEBUG):
            # our own cluster only (a scheduler the user runs keeps its logging as it is);
            # a plugin, so that a worker the nanny restarts gets the filter too
            from ._dask_worker_plugin import QuietComputeFailures

            client.register_plugin(QuietComputeFailures())
            restarts = _OwnWorkerRestarts()
            for name in RESTART_LOGGERS:
                logging.getLogger(name).addFilter(restarts)
        else:
            restarts = None
    except BaseException:  # Ctrl-C, SIGTERM or a failure: no worker process left behind
        _close_quietly(client, cluster)
        raise
    log.info(
        "started a LocalCluster: %d worker processes x %d threads (%s)",
        n,
        threads_per_worker,
        "TLS, this process's own certificate" if security is not None else "plain TCP",
    )

    def _close(quiet: bool = False) -> None:
        try:
            if quiet:
                _silence_workers(client)
                with _logging_silenced():
                    client.close()
                    cluster.close()
            else:
                client.close()
                cluster.close()
        except Exception:  # noqa: BLE001 - best effort at interpreter exit
            pass
        for name in RESTART_LOGGERS:  # a cluster started later logs as Dask does
            logging.getLogger(name).removeFilter(restarts)

    atexit.register(_close)
    _STARTED.append(_close)
    return client


#: Seconds :func:`_silence_workers` waits for the workers to answer.
SILENCE_TIMEOUT_S = 5.0


def _silence_logging() -> None:
    """Run on each worker of quash's own LocalCluster when the command is interrupted:
    the worker is about to be closed mid-task, and says so in warnings and tracebacks
    (tasks cancelled, heartbeats to a scheduler that is closing) the user does not need."""
    logging.disable(logging.CRITICAL)


def _silence_workers(client: Any, timeout: float = SILENCE_TIMEOUT_S) -> None:
    """:func:`_silence_logging` on every worker of ``client``, waiting at most ``timeout``
    seconds (a worker that does not answer is closed all the same)."""
    thread = threading.Thread(
        target=lambda: client.run(_silence_logging, on_error="ignore"),
        name="quash: silence Dask workers",
        daemon=True,
    )
    thread.start()
    thread.join(timeout)


@contextlib.contextmanager
def _logging_silenced() -> Iterator[None]:
    """No log record in this process while quash's own cluster is closed on Ctrl-C (its
    scheduler and nannies run here), and afterwards none of the client's abandoned
    waits ("Task exception was never retrieved ... AllExit")."""
    _drop_abandoned_waits()
    previous = logging.root.manager.disable
    logging.disable(logging.CRITICAL)
    try:
        yield
    finally:
        logging.disable(previous)


class _AbandonedWaits(logging.Filter):
    """Drops asyncio's "Task exception was never retrieved" of a wait of a Dask client
    that was closed while it waited (``distributed.client.AllExit``, Dask's own signal
    to stop waiting, which no caller retrieves once the command was interrupted)."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not (
            str(record.msg).startswith("Task exception was never retrieved")
            and type(exc).__name__ == "AllExit"
            and type(exc).__module__.startswith("distributed")
        )


def _drop_abandoned_waits() -> None:
    logger = logging.getLogger("asyncio")
    if not any(isinstance(f, _AbandonedWaits) for f in logger.filters):
        logger.addFilter(_AbandonedWaits())


#: Seconds :func:`check_scheduler_address` waits for a TCP connection to the scheduler.
PROBE_TIMEOUT_S = 5.0

_START_HINT = (
    "Start one with `dask scheduler` and workers with `dask worker ADDRESS`, or leave out "
    "--scheduler to run a local cluster (see docs/scale.md)."
)


def check_scheduler_address(address: str, timeout: float = PROBE_TIMEOUT_S) -> None:
    """Fail fast when nothing can answer at a scheduler ``address``.

    An unknown scheme or a missing port is a :class:`UsageError`; a host that does not
    resolve, a refused connection or no answer within ``timeout`` seconds (TCP and TLS
    addresses) is a :class:`QuashError` with the fix, instead of Dask's retries until its
    connect timeout (30 s by default).
    """
    import socket

    from ..core.errors import UsageError

    _require_distributed()
    from distributed.comm import parse_address
    from distributed.comm.addressing import get_address_host_port

    try:
        scheme, _ = parse_address(address)
        host, port = get_address_host_port(address)
    except ValueError as exc:
        raise UsageError(
            f"--scheduler {address!r} is not a Dask scheduler address ({exc}). Give the "
            "scheduler's address as `dask scheduler` prints it: tcp://HOST:8786."
        ) from None
    if scheme not in ("tcp", "tls"):
        return  # ws://, ucx://: left to Dask
    where = f"{host}:{port}"
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise QuashError(
            f"Cannot reach the Dask scheduler at {address}: the host {host!r} is not known "
            f"({exc.strerror or exc}). Check the host name. {_START_HINT}"
        ) from None
    last: OSError | None = None
    for family, kind, proto, _, sockaddr in infos:
        try:
            with socket.socket(family, kind, proto) as sock:
                sock.settimeout(timeout)
                sock.connect(sockaddr)
                if scheme == "tcp":
                    _expect_dask_greeting(sock, address, timeout)
            return
        except QuashError:
            raise
        except OSError as exc:
            last = exc
    if isinstance(last, ConnectionRefusedError):
        why = f"nothing listens at {where} (connection refused)"
    elif isinstance(last, TimeoutError):
        why = f"no answer from {where} within {timeout:g} s (a firewall, or the host is down)"
    else:
        why = f"cannot connect to {where} ({last})"
    raise QuashError(f"Cannot reach the Dask scheduler at {address}: {why}. {_START_HINT}")


def _expect_dask_greeting(sock: Any, address: str, timeout: float) -> None:
    """A Dask scheduler writes its handshake as soon as a connection opens (over plain
    TCP); a web server or any other service waits for a request. Without this check,
    ``Client`` would wait on such a peer forever."""

    try:
        first = sock.recv(8)
    except TimeoutError:
        first = None
    except OSError:
        first = b""
    if first and not first.startswith(b"HTTP"):
        return
    what = (
        "a web server answered (the dashboard?)"
        if first
        else f"it accepted the connection but sent no Dask handshake within {timeout:g} s"
        if first is None
        else "it closed the connection at once"
    )
    raise QuashError(
        f"{address} is not a Dask scheduler: {what}. Check the port: the scheduler listens "
        "on 8786 by default (`dask scheduler` prints its address), its dashboard on 8787."
    )


def client_from_cli(address: str | None) -> Any:
    """The ``Client`` for ``--scheduler ADDRESS``; without an address, a local cluster.

    The address is probed first (:func:`check_scheduler_address`), so a scheduler that
    is not there fails within seconds; something that answers there but is not a Dask
    scheduler (a web server, the dashboard's port 8787) is a :class:`QuashError` too.

    Examples
    --------
    >>> client = client_from_cli("tcp://scheduler:8786")  # doctest: +SKIP
    """
    if address is None:
        return local_cluster_client()
    distributed = _require_distributed()
    check_scheduler_address(address)
    try:
        import dask

        timeout = dask.config.get("distributed.comm.timeouts.connect", "30s")
        client = distributed.Client(address, timeout=timeout)
    except (OSError, TimeoutError) as exc:
        raise QuashError(
            f"Cannot reach the Dask scheduler at {address} ({exc}). {_START_HINT}"
        ) from None
    except Exception as exc:  # noqa: BLE001 - a peer that is not Dask fails in many ways
        raise QuashError(
            f"{address} answered, but not as a Dask scheduler ({type(exc).__name__}: "
            f"{str(exc)[:200]}). Check the port: the scheduler listens on 8786 by default, "
            "its dashboard (a web page, not the scheduler) on 8787."
        ) from None
    atexit.register(client.close)
    # the user's own scheduler and workers: closed as Dask closes them, quiet or not
    _STARTED.append(lambda quiet=False: client.close())
    return client


#: Closers of the clients (and local clusters) started by :func:`local_cluster_client` and
#: :func:`client_from_cli`, for :func:`close_started_clients`.
_STARTED: list[Any] = []


def close_started_clients(quiet: bool = False) -> int:
    """Close every client and local cluster this module started; how many were closed.

    The ``quash`` command calls it when a command ends, so that a command run inside a
    longer-lived process (a notebook, a test) leaves no default client behind for the
    next Dask computation to find. Also registered at interpreter exit.

    ``quiet`` (the command was interrupted: Ctrl-C or SIGTERM): a local cluster quash
    started is closed without a word from its workers, scheduler or client, which
    would otherwise print the tasks they cancel and heartbeat tracebacks under the
    command's one line. A normal end closes as Dask does, errors and all.
    """
    n = 0
    while _STARTED:
        close = _STARTED.pop()
        try:
            close(quiet=quiet)
        except Exception:  # noqa: BLE001 - closing must never hide the command's result
            log.debug("closing a Dask client failed", exc_info=True)
        n += 1
    return n


def current_client(client: Any = None) -> Any:
    """``client``, else the process's default distributed client, else None (threads)."""
    if client is not None:
        return client
    try:
        from distributed import default_client

        return default_client()
    except (ImportError, ValueError):
        return None
