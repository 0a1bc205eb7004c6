"""``--scheduler ADDRESS`` fails fast, with the fix, when no Dask scheduler answers there."""

from __future__ import annotations

import socket
import threading

import pytest

pytest.importorskip("distributed")

from quash_plugins.core.errors import QuashError, UsageError  # noqa: E402
from quash_plugins.engine.dask_client import (  # noqa: E402
    check_scheduler_address,
    client_from_cli,
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_refused_port_names_the_fix() -> None:
    addr = f"tcp://127.0.0.1:{_free_port()}"
    with pytest.raises(QuashError, match="nothing listens at 127.0.0.1:.*dask scheduler"):
        client_from_cli(addr)


def test_unknown_host() -> None:
    with pytest.raises(QuashError, match="host 'no-such-host.invalid' is not known"):
        check_scheduler_address("tcp://no-such-host.invalid:8786")


@pytest.mark.parametrize("address", ["http://127.0.0.1:8787", "tcp://127.0.0.1"])
def test_not_an_address(address: str) -> None:
    with pytest.raises(UsageError, match="not a Dask scheduler address.*tcp://HOST:8786"):
        check_scheduler_address(address)


def test_silent_peer_is_refused_not_waited_on() -> None:
    # A listening socket that never writes: the connection completes from the backlog,
    # and a dask Client would wait on it for ever.
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        port = server.getsockname()[1]
        with pytest.raises(QuashError, match="sent no Dask handshake within 0.2 s.*8786"):
            check_scheduler_address(f"tcp://127.0.0.1:{port}", timeout=0.2)


def test_web_server_is_named() -> None:
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)

    def answer() -> None:
        conn, _ = server.accept()
        with conn:
            conn.sendall(b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n")

    t = threading.Thread(target=answer, daemon=True)
    t.start()
    try:
        with pytest.raises(QuashError, match="a web server answered.*dashboard on 8787"):
            check_scheduler_address(f"tcp://127.0.0.1:{server.getsockname()[1]}", timeout=5)
    finally:
        t.join(5)
        server.close()


def test_a_real_scheduler_passes() -> None:
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=0, host="127.0.0.1", dashboard_address="127.0.0.1:0", protocol="tcp://"
    ) as cluster:
        check_scheduler_address(cluster.scheduler_address)


def test_the_local_cluster_serves_on_loopback_only_and_takes_a_free_web_port() -> None:
    """The LocalCluster that --backend dask starts listens on 127.0.0.1 only: its
    scheduler, its workers and the scheduler's web server (health and metrics routes).
    That web server takes a free port, so a Dask dashboard already on 8787 (the user's
    own, or another quash run's) neither collides nor prints "Port 8787 is already in
    use"."""
    import warnings

    from quash_plugins.engine.dask_client import local_cluster_client

    held = socket.socket()
    try:
        held.bind(("127.0.0.1", 8787))  # as a running dashboard would
        held.listen()
    except OSError:  # something already listens there: the same case
        pass
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            client = local_cluster_client(n_workers=1, memory_limit="1GiB")
        cluster = client.cluster
        try:
            assert not [w for w in caught if "already in use" in str(w.message)]
            web = cluster.scheduler.http_server
            assert web.address == "127.0.0.1" and web.port != 8787
            addresses = [cluster.scheduler.address, *(w.address for w in cluster.workers.values())]
            assert addresses and all("://127.0.0.1:" in a for a in addresses), addresses
        finally:
            client.close()
            cluster.close()
    finally:
        held.close()
