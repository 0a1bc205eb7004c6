"""The Rerun outputs as a user meets them, in real subprocesses with timeouts.

- ``--spawn`` without a display says so in one line, writes what was asked and exits
  (it used to hang for ever in ``RecordingStream.flush`` and leave a ``.tmp`` file);
- a viewer that cannot start, or a ``--connect`` address where nothing listens, is one
  line too;
- ``--serve-web`` listens on 127.0.0.1 only (its HTTP port used to be on 0.0.0.0),
  checked in the kernel's socket table;
- ``quash demo --serve-web`` started in the background by a shell (which ignores SIGINT
  for it) stops cleanly on SIGINT and on SIGTERM, leaving no temporary file and no
  server behind. (SIGTERM while a recording is written: tests/cli/test_signals.py.)
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("rerun")

from _procs import Lines, free_port  # noqa: E402

from quash_plugins.viewer import display_available, rerun_executable  # noqa: E402

CLI = [sys.executable, "-c", "from quash_plugins.cli.main import main; raise SystemExit(main())"]


def viewer_port_cli(port: int) -> list[str]:
    """The CLI with the native viewer ``--spawn`` opens, and the default ``--grpc-port``,
    on ``port`` instead of 9876: a viewer that another run, or a test running beside this
    one, opened there made ``--spawn`` take it for this run's ('already listens')."""
    code = (
        "from quash_plugins.viewer import _sinks\n"
        "assert _sinks.DEFAULT_GRPC_PORT == 9876, 'the native viewer port moved'\n"
        f"_sinks.DEFAULT_GRPC_PORT = {int(port)}\n"
        "from quash_plugins.cli.main import main\n"
        "raise SystemExit(main())"
    )
    return [sys.executable, "-c", code]


pytestmark = pytest.mark.skipif(
    rerun_executable() is None, reason="the rerun executable of the SDK is not installed"
)


def headless_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    return {**env, "PYTHONUNBUFFERED": "1", "COLUMNS": "120", **extra}


def listening(ports: set[int]) -> set[tuple[str, int]]:
    """(address, port) of every listening TCP socket on ``ports``, from /proc/net."""
    found = set()
    for name, width in (("tcp", 8), ("tcp6", 32)):
        table = Path("/proc/net") / name
        if not table.exists():
            continue
        for line in table.read_text().splitlines()[1:]:
            fields = line.split()
            local, state = fields[1], fields[3]
            if state != "0A":  # TCP_LISTEN
                continue
            hex_ip, hex_port = local.split(":")
            port = int(hex_port, 16)
            if port not in ports:
                continue
            raw = bytes.fromhex(hex_ip)
            # The kernel prints each 32-bit word in host (little-endian) order.
            raw = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
            family = socket.AF_INET if width == 8 else socket.AF_INET6
            found.add((socket.inet_ntop(family, raw), port))
    return found


@pytest.fixture(scope="module")
def demo_cache(tmp_path_factory) -> str:
    """One QuASH cache for this module's ``quash demo`` runs: the tiny scene is built once."""
    return str(tmp_path_factory.mktemp("demo-cache"))


@pytest.fixture
def small_map(tmp_path):
    from _viewer_maps import voxel_map, write_table_config

    from quash_plugins.adapters._npz import write_npz_map

    return write_npz_map(voxel_map(), tmp_path / "map.npz"), write_table_config(tmp_path)


def run_cli(args: list[str], cwd: Path, env: dict, timeout: float = 300, cli=CLI):
    return subprocess.run(
        [*cli, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )


def assert_no_tmp(folder: Path) -> None:
    left = [p.name for p in folder.rglob("*") if p.name.endswith(".tmp")]
    assert not left, f"temporary files left behind: {left}"


@pytest.mark.slow
def test_demo_spawn_without_a_display_says_so_and_finishes(tmp_path, demo_cache):
    """The issue's command: ``quash demo --spawn`` on a machine with no display."""
    out = tmp_path / "demo"
    env = headless_env(QUASH_CACHE_DIR=demo_cache)
    proc = run_cli(["demo", "--tiny", "--spawn", "--out", str(out)], tmp_path, env)
    assert proc.returncode == 0, proc.stderr
    spawn_lines = [ln for ln in proc.stderr.splitlines() if "--spawn" in ln]
    assert len(spawn_lines) == 1, proc.stderr
    assert "no display" in spawn_lines[0]
    from rerun.chunk import RrdReader

    assert RrdReader(out / "demo.rrd").recordings()  # a complete recording
    assert (out / "demo.md").is_file()
    assert_no_tmp(out)


def test_spawn_when_the_viewer_cannot_start(tmp_path, small_map):
    """A display is set but unusable: the viewer exits at start; one line, and on."""
    map_path, cfg = small_map
    env = headless_env(DISPLAY=":93517")  # no X server there
    rrd = tmp_path / "out.rrd"
    proc = run_cli(
        ["query", str(map_path), "chair", "-c", str(cfg), "--spawn", "--rrd", str(rrd)],
        tmp_path,
        env,
        cli=viewer_port_cli(free_port()),
    )
    assert proc.returncode == 0, proc.stderr
    spawn_lines = [ln for ln in proc.stderr.splitlines() if "--spawn" in ln]
    assert len(spawn_lines) == 1 and "did not start" in spawn_lines[0], proc.stderr
    assert rrd.is_file() and "chair" in proc.stdout
    assert_no_tmp(tmp_path)


def test_connect_to_nothing_says_so_and_writes_the_file(tmp_path, small_map):
    map_path, cfg = small_map
    port = free_port()
    rrd = tmp_path / "out.rrd"
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    proc = run_cli(
        ["query", str(map_path), "chair", "-c", str(cfg), "--connect", url, "--rrd", str(rrd)],
        tmp_path,
        headless_env(),
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if "--connect" in ln]
    assert len(lines) == 1 and f"127.0.0.1:{port}" in lines[0], proc.stderr
    assert rrd.is_file()
    assert_no_tmp(tmp_path)


def test_display_detection():
    if sys.platform.startswith("linux"):
        assert not display_available({})
        assert display_available({"WAYLAND_DISPLAY": "wayland-0"})
        assert display_available({"DISPLAY": ":0"})


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net")
def test_serve_web_listens_on_loopback_only_and_stops_on_sigterm(tmp_path, small_map):
    map_path, cfg = small_map
    web, grpc = free_port(), free_port()
    cli = subprocess.Popen(
        [*CLI, "query", str(map_path), "chair", "-c", str(cfg), "--serve-web"]
        + ["--web-port", str(web), "--grpc-port", str(grpc)],
        cwd=tmp_path,
        env=headless_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    err, out = Lines(cli.stderr), Lines(cli.stdout)
    try:
        err.wait_for("Serving the Rerun web viewer", 120, cli)
        sockets = listening({web, grpc})
        assert {port for _, port in sockets} == {web, grpc}, sockets
        assert {addr for addr, _ in sockets} == {"127.0.0.1"}, sockets
        cli.send_signal(signal.SIGTERM)
        assert cli.wait(timeout=60) == 0, err.text()
    finally:
        if cli.poll() is None:
            cli.kill()
            cli.wait(timeout=30)
    assert "stopped serving" in err.text()
    assert "chair" in out.text()
    deadline = time.monotonic() + 10
    while listening({web, grpc}) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not listening({web, grpc}), "a server outlived the command"


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_demo_serve_web_in_the_background_stops_on(sig, tmp_path, demo_cache):
    """``quash demo --serve-web &`` from a script: the shell makes the job ignore SIGINT."""
    web, grpc = free_port(), free_port()
    out = tmp_path / "demo"
    cmd = " ".join(
        [*(f"'{a}'" for a in CLI), "demo", "--tiny", "--serve-web", "--out", str(out)]
        + ["--web-port", str(web), "--grpc-port", str(grpc)]
    )
    shell = subprocess.Popen(
        ["bash", "-c", f"{cmd} & echo $!; wait $!"],
        cwd=tmp_path,
        env=headless_env(QUASH_CACHE_DIR=demo_cache),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    err, stdout = Lines(shell.stderr), Lines(shell.stdout)
    try:
        err.wait_for("Serving the Rerun web viewer", 300, shell)
        pid = int(stdout.lines[0])  # the job, started with SIGINT ignored
        os.kill(pid, sig)
        assert shell.wait(timeout=60) == 0, err.text()
    finally:
        if shell.poll() is None:
            shell.kill()
            shell.wait(timeout=30)
    assert "stopped serving" in err.text()
    assert (out / "demo.rrd").is_file()
    assert_no_tmp(out)
    deadline = time.monotonic() + 10
    while listening({web, grpc}) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not listening({web, grpc}), "a server outlived the command"


def _listen_on(host: str) -> socket.socket:
    """A listening socket on a free port of ``host`` (skips where the address is not
    this machine's, e.g. 127.0.0.2 outside Linux)."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, 0))
    except OSError as exc:
        sock.close()
        pytest.skip(f"cannot listen on {host}: {exc}")
    sock.listen()
    return sock


def test_serve_web_on_every_interface_refuses_a_port_taken_on_another_address(tmp_path, small_map):
    """The walkthrough's case: a program listens on port P of another address of the
    machine (here 127.0.0.2), so binding 0.0.0.0:P fails. The check connected to
    127.0.0.1:P, found nothing, and the command printed the gRPC server's raw error, then
    served a web viewer pointing at the other program. Now it is refused first."""
    map_path, cfg = small_map
    web = free_port()
    with _listen_on("127.0.0.2") as other:
        grpc = other.getsockname()[1]
        args = ["query", str(map_path), "chair", "-c", str(cfg), "--serve-web"]
        args += ["--bind", "0.0.0.0", "--web-port", str(web), "--grpc-port", str(grpc)]
        try:
            proc = run_cli(args, tmp_path, headless_env(), timeout=90)
        except subprocess.TimeoutExpired as exc:
            pytest.fail(f"it served instead of refusing the busy port:\n{exc.stderr}")
    assert proc.returncode == 1, proc.stderr
    assert f"Port {grpc} on 0.0.0.0 is in use" in proc.stderr
    assert "--grpc-port PORT" in proc.stderr
    assert "Failed to listen" not in proc.stderr  # the gRPC server never started
    assert "Rerun web viewer:" not in proc.stderr  # nor the web viewer
    assert not listening({web, grpc}) - {("127.0.0.2", grpc)}


def _refusal(**options) -> str:
    """The message of a SinkRerunLogger refused with these ViewerOptions."""
    from quash_plugins.core.errors import QuashError
    from quash_plugins.viewer import SinkRerunLogger, ViewerOptions

    try:
        logger = SinkRerunLogger(ViewerOptions(serve_web=True, **options))
    except QuashError as exc:
        return str(exc)
    logger._discard()  # it started: stop its servers without serving
    logger.recording.disconnect()
    pytest.fail(f"{options} was not refused")


def test_serve_web_refuses_a_busy_port_of_its_own_address():
    with _listen_on("127.0.0.1") as other:
        port = other.getsockname()[1]
        said = _refusal(bind="127.0.0.1", grpc_port=port, web_port=free_port())
        assert f"Port {port} on 127.0.0.1 is in use" in said and "--grpc-port PORT" in said
        said = _refusal(bind="127.0.0.1", grpc_port=free_port(), web_port=port)
        assert f"Port {port} on 127.0.0.1 is in use" in said and "--web-port PORT" in said


def test_serve_web_on_an_address_the_machine_does_not_have_names_bind():
    """192.0.2.99 (TEST-NET-1) is no interface's: no port can help, --bind can."""
    from quash_plugins.core.errors import UsageError

    with pytest.raises(UsageError) as refused:
        from quash_plugins.viewer import SinkRerunLogger, ViewerOptions

        SinkRerunLogger(
            ViewerOptions(
                serve_web=True, bind="192.0.2.99", web_port=free_port(), grpc_port=free_port()
            )
        )
    said = str(refused.value)
    assert "--bind 192.0.2.99 is not an address of this machine" in said, said
    assert "--web-port" not in said and "--grpc-port" not in said


@pytest.mark.parametrize("command", ["query", "eval"])
def test_serve_web_refuses_a_busy_port_before_any_query_runs(
    command, tmp_path, small_map, monkeypatch, capsys
):
    """The viewer opened only once every query had run: a busy --web-port was said after
    that work (minutes on a real map), and --serve-web's URL, which docs/rerun.md says is
    printed before the query runs so it can be opened meanwhile, came after it too."""
    from quash_plugins.cli.main import main
    from quash_plugins.engine.pipeline import Quash

    map_path, cfg = small_map
    ran = []
    query_many = Quash.query_many

    def counted(self, *args, **kwargs):
        ran.append(args)
        return query_many(self, *args, **kwargs)

    monkeypatch.setattr(Quash, "query_many", counted)
    queries = ["chair"] if command == "query" else ["--queries", "chair"]
    with _listen_on("127.0.0.1") as other:
        busy = other.getsockname()[1]
        args = [command, str(map_path), *queries, "-c", str(cfg), "--serve-web"]
        code = main([*args, "--web-port", str(busy), "--grpc-port", str(free_port())])
    err = capsys.readouterr().err
    assert code == 1, err
    assert f"Port {busy} on 127.0.0.1 is in use" in err and "--web-port PORT" in err
    assert not ran, "the queries ran before the busy port was said"
    assert_no_tmp(tmp_path)


def test_spawn_beside_serve_web_on_one_port_is_refused_before_a_viewer_starts(tmp_path, small_map):
    """``--spawn --serve-web`` with a display: the native viewer listens on
    127.0.0.1:9876, the default --grpc-port; the server then found the port taken by the
    viewer quash had just opened ('in use (another program listens on it)'), and that
    viewer stayed open. Refused first, naming the port to give; another --grpc-port
    passes this check."""
    from quash_plugins.viewer._sinks import SinkRerunLogger, ViewerOptions

    map_path, cfg = small_map
    rrd = tmp_path / "out.rrd"
    env = headless_env(DISPLAY=":93517")
    port = free_port()  # the viewer's and the default --grpc-port (9876 in a release)
    proc = run_cli(
        ["query", str(map_path), "chair", "-c", str(cfg), "--spawn", "--serve-web"]
        + ["--rrd", str(rrd), "--web-port", str(free_port())],
        tmp_path,
        env,
        timeout=120,
        cli=viewer_port_cli(port),
    )
    assert proc.returncode == 2, proc.stderr
    assert f"both need port {port} on 127.0.0.1" in proc.stderr
    assert f"--grpc-port {port + 1}" in proc.stderr and "--spawn" in proc.stderr
    assert "chair" not in proc.stdout and not rrd.exists()  # before any query or file
    assert_no_tmp(tmp_path)
    opts = ViewerOptions(spawn=True, serve_web=True, grpc_port=free_port())
    logger = SinkRerunLogger.__new__(SinkRerunLogger)
    logger.grpc_port, logger.bind = opts.grpc_port, "127.0.0.1"
    logger._check_spawn_beside_serve()  # another port: nothing to refuse
