"""The LocalCluster that ``--backend dask`` starts accepts no client but its own.

It listens on 127.0.0.1, which every user of a shared machine can reach, and a Dask
scheduler runs whatever a client sends it. Over plain TCP, another user could connect
and run code in its workers as you (``Client(ADDRESS).run(...)``); now the cluster
speaks mutual TLS with a certificate made for the process that started it.
"""

from __future__ import annotations

import logging

import pytest

distributed = pytest.importorskip("distributed")

from quash_plugins.core.once import forget  # noqa: E402
from quash_plugins.engine import dask_client  # noqa: E402
from quash_plugins.engine.dask_client import (  # noqa: E402
    close_started_clients,
    local_cluster_client,
    local_cluster_security,
)


def _double(x):
    return 2 * x


def test_local_cluster_refuses_clients_without_its_certificate():
    pytest.importorskip("cryptography")
    from distributed.security import Security

    client = local_cluster_client(n_workers=1, memory_limit="1GiB")
    try:
        address = client.scheduler.address
        assert address.startswith("tls://127.0.0.1:"), address
        assert client.submit(_double, 21).result(timeout=60) == 42  # its own client works
        plain = address.replace("tls://", "tcp://")
        with pytest.raises(Exception):  # noqa: B017 - refused however Dask words it
            distributed.Client(plain, timeout=5)
        with pytest.raises(Exception):  # noqa: B017 - TLS, but another certificate
            distributed.Client(address, timeout=5, security=Security.temporary())
    finally:
        close_started_clients()


def test_without_cryptography_the_cluster_is_plain_tcp_and_says_so(monkeypatch, caplog):
    from distributed.security import Security

    def no_cryptography(*args, **kwargs):
        raise ImportError("Using `Security.temporary` requires `cryptography`")

    monkeypatch.setattr(Security, "temporary", classmethod(no_cryptography))
    forget("dask-plain-tcp")
    caplog.set_level(logging.WARNING, logger=dask_client.__name__)
    assert local_cluster_security() is None
    assert local_cluster_security() is None
    warnings = [r for r in caplog.records if "without TLS" in r.getMessage()]
    assert len(warnings) == 1  # once per process
    assert "any user of it could run code" in warnings[0].getMessage()
    assert "quash-plugins[dask]" in warnings[0].getMessage()
