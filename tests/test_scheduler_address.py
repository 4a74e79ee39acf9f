"""--scheduler addresses are checked before anything runs (the schemes dask.distributed takes); --scheduler-file reads one."""

import json
import re
import threading

import pytest
from click.testing import CliRunner

from patchcloud.core import PatchcloudIOError, PatchcloudValueError
from patchcloud.stream import RunOptions
from patchcloud.stream.cli import main
from patchcloud.stream.engine.runner import check_scheduler, scheduler_from_file


@pytest.mark.parametrize("address", ["tcp://10.0.0.1:8786", "tls://node7:8786", "ucx://node7", "ws://[::1]:8786", "wss://a.b.c:1",
                                     "node7:8786", "threads", "auto"])
def test_addresses_dask_takes_are_taken(address):
    assert RunOptions(scheduler=address).scheduler == address


@pytest.mark.parametrize("address", ["htps://node7:8786", "node7", "tcp://node7:99999", "tcp://", "", "thread", "tcp://a b:1", 8786])
def test_other_addresses_are_one_error_listing_what_is_taken(address):
    with pytest.raises(PatchcloudValueError, match=r"scheduler must be one of auto, threads, processes, synchronous or a dask "
                                                   r"scheduler address SCHEME://HOST\[:PORT\] with SCHEME one of tcp, tls, ucx, ws, wss"):
        check_scheduler(address)


def test_a_scheduler_file_gives_its_address(tmp_path):
    f = tmp_path / "scheduler.json"
    f.write_text(json.dumps({"type": "Scheduler", "address": "tls://10.1.2.3:8786", "workers": {}}))
    assert scheduler_from_file(f) == "tls://10.1.2.3:8786"
    f.write_text("{}")
    with pytest.raises(PatchcloudIOError, match="scheduler.json: not a dask scheduler file with an address"):
        scheduler_from_file(f)


def test_the_cli_checks_both_before_reading_the_input(tmp_path):
    f = tmp_path / "scheduler.json"
    f.write_text(json.dumps({"address": "smtp://x:25"}))
    for args, said in ([["--scheduler", "htps://x:1"], "scheduler must be one of"],
                       [["--scheduler-file", str(f)], "got 'smtp://x:25'"],
                       [["--scheduler-file", str(f), "--scheduler", "threads"], "not both"]):
        r = CliRunner().invoke(main, ["normals", str(tmp_path / "none.las"), str(tmp_path / "out.las"), *args])
        assert r.exit_code == 2 and r.output.count("\n") == 1 and said in r.output, r.output


def _serve(reply: bytes | None):
    """A TCP server on 127.0.0.1 that sends ``reply`` to each connection (None: nothing), as a thread; (server, port)."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))

    def accept():
        while True:
            try:
                conn, _ = server.accept()
            except OSError:  # closed
                return
            if reply is not None:
                conn.sendall(reply)

    threading.Thread(target=accept, daemon=True).start()
    return server, server.getsockname()[1]


@pytest.mark.parametrize("reply, says", [
    (None, "it said nothing in 0.5 s"),  # a server that waits for a request: the dashboard's port, say
    (b"HTTP/1.1 400 Bad Request\r\n\r\n", "its first bytes were b'HTTP/1.1'"),
])
def test_a_server_that_is_not_a_scheduler_is_one_error_not_a_wait_for_ever(reply, says, monkeypatch):
    """dask's client waits for ever for the handshake of a server that is not a scheduler (found by review J: a run
    pointed at the dashboard's port hung); the probe gives up after its time limit, with one line."""
    import patchcloud.stream.engine.scheduler_probe as probe
    from patchcloud.stream.engine.runner import Runner

    server, port = _serve(reply)
    try:
        with pytest.raises(PatchcloudValueError, match=f"127.0.0.1:{port}: something listens there but it is not a dask scheduler "
                                                       rf"\({re.escape(says)}"):
            probe.probe_scheduler(f"tcp://127.0.0.1:{port}", timeout=0.5)
        monkeypatch.setattr(probe, "PROBE_SECONDS", 0.5)
        raised = []

        def run():  # and so does a run (on a thread: without the probe it would wait for ever)
            try:
                Runner(f"127.0.0.1:{port}")
            except PatchcloudValueError as exc:
                raised.append(str(exc))

        t = threading.Thread(target=run, daemon=True)
        t.start()
        t.join(30)
        assert not t.is_alive(), "the run waits for a scheduler's handshake that never comes"
        assert raised and "not a dask scheduler" in raised[0]
    finally:
        server.close()


def test_a_scheduler_s_handshake_passes_and_a_closed_port_is_tried_until_the_time_limit():
    import socket
    import struct
    import time

    from patchcloud.stream.engine.scheduler_probe import probe_scheduler

    server, port = _serve(struct.pack("<Q", 1) + struct.pack("<Q", 40))  # one frame of 40 bytes: how a scheduler starts
    try:
        probe_scheduler(f"tcp://127.0.0.1:{port}", timeout=5)
        probe_scheduler(f"127.0.0.1:{port}", timeout=5)  # HOST:PORT is tcp
    finally:
        server.close()
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    t = time.monotonic()
    with pytest.raises(PatchcloudValueError, match=f"cannot reach the dask scheduler at tcp://127.0.0.1:{closed} .*for 1.2 s"):
        probe_scheduler(f"tcp://127.0.0.1:{closed}", timeout=1.2)
    assert time.monotonic() - t >= 0.9  # tried again while the time lasted (a scheduler still starting)
