"""Whether a dask scheduler answers at a TCP address, before dask's client is let connect to it.

dask's client, once its TCP connection is made, waits for the scheduler's
handshake with no time limit: pointed at another kind of server (the
dashboard's port, 8787, for the scheduler's, 8786; any web server), it
waits for ever, and the run with it.  A dask scheduler sends its handshake
as soon as a connection is made, without waiting for the client's (a
message of a few frames: its first 8 bytes are the number of frames, little
endian).  :func:`probe_scheduler` connects, waits up to its time limit for
those 8 bytes, and says what it found; addresses of the other schemes
(``tls``, ``ucx``, ``ws``, ``wss``) are left to dask.
"""

from __future__ import annotations

import re
import socket
import struct
import time

from patchcloud.core import PatchcloudValueError

__all__ = ["probe_scheduler", "ADDRESS", "PROBE_SECONDS", "RETRY_SECONDS", "DEFAULT_PORT"]

#: A scheduler address: ``[SCHEME://]HOST[:PORT]``, HOST a name, an IPv4 address or an IPv6 one in brackets (groups
#: ``scheme``, ``host``, ``port``; :func:`patchcloud.stream.engine.runner.check_scheduler` says which schemes are taken).
ADDRESS = re.compile(r"^(?:(?P<scheme>[A-Za-z0-9]+)://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-]+)(?::(?P<port>\d{1,5}))?$")

#: How long (seconds) the scheduler is waited for: dask's own connect timeout here.
PROBE_SECONDS = 20.0
#: A refused connection is tried again after this many seconds, until the time limit.
RETRY_SECONDS = 0.5
#: dask's default scheduler port (an address without a port).
DEFAULT_PORT = 8786
#: A dask message holds at most this many frames (a plausible first 8 bytes).
MOST_FRAMES = 1 << 16


def probe_scheduler(address: str, timeout: float | None = None) -> None:
    """Return when a dask scheduler answers at the TCP ``address`` (``tcp://HOST[:PORT]`` or ``HOST:PORT``), else raise.

    Raises
    ------
    PatchcloudValueError
        Nothing listens there (connections refused for ``timeout``
        seconds, as dask's client tries), or what answers is not a dask scheduler (it
        sends nothing within ``timeout`` seconds, default
        :data:`PROBE_SECONDS`, or not a dask message), in one line naming
        the address.

    Examples
    --------
    >>> import socket
    >>> server = socket.create_server(("127.0.0.1", 0))        # listens, says nothing: not a scheduler
    >>> port = server.getsockname()[1]
    >>> probe_scheduler(f"tcp://127.0.0.1:{port}", timeout=0.2)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: tcp://127.0.0.1:...: something listens there but it is not a dask scheduler (it said nothing in 0.2 s; the dashboard's port, 8787 by default, is not the scheduler's, 8786)
    >>> server.close()
    """
    m = ADDRESS.match(address)
    if m is None or m["scheme"] not in (None, "tcp"):  # (an address check_scheduler refused: dask says what is wrong)
        return
    host, port = m["host"].strip("[]"), m["port"]
    wait = PROBE_SECONDS if timeout is None else float(timeout)
    deadline = time.monotonic() + wait
    while True:  # as dask's client: a scheduler still starting refuses connections for a while
        try:
            conn = socket.create_connection((host, int(port) if port else DEFAULT_PORT), timeout=wait)
            break
        except ConnectionRefusedError as exc:
            if time.monotonic() + RETRY_SECONDS > deadline:
                raise PatchcloudValueError(f"cannot reach the dask scheduler at {address} ({exc}, for {wait:g} s)") from exc
            time.sleep(RETRY_SECONDS)
        except OSError as exc:
            raise PatchcloudValueError(f"cannot reach the dask scheduler at {address} ({exc})") from exc
    with conn:
        got = b""
        try:
            while len(got) < 8:
                more = conn.recv(8 - len(got))
                if not more:
                    break
                got += more
        except OSError:  # a timeout (socket.timeout is an OSError), a reset
            pass
    if len(got) == 8 and 0 < struct.unpack("<Q", got)[0] <= MOST_FRAMES:
        return
    said = f"it said nothing in {wait:g} s" if not got else f"its first bytes were {got!r}"
    raise PatchcloudValueError(f"{address}: something listens there but it is not a dask scheduler ({said}; the dashboard's port, "
                               f"8787 by default, is not the scheduler's, {DEFAULT_PORT})")
