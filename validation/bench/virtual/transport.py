"""Where the virtual bench's serial line goes: a pseudo-terminal or a loopback socket.

Both can vanish and come back, as a USB serial adapter does when its cable is
pulled: :meth:`disconnect` closes the line (the host's reads fail),
:meth:`reconnect` opens it again *at the same address* (for the
pseudo-terminal, a symbolic link that is pointed at the new terminal; for the
socket, the same host and port).

:attr:`heard` tells whether the host has said anything on the line since it
came up (or, for the socket, since the host connected). Until then the
device cannot know that the host's port is open: a host's port opening
discards what was waiting (pyserial flushes its input when it opens a port,
a socket included), so what was written before may never be read.

Example
-------
>>> from electrosense.validation.bench.virtual.transport import PtyTransport
>>> t = PtyTransport()                  # doctest: +SKIP
>>> t.path                              # doctest: +SKIP
'/tmp/esense-bench-k2j3/bench'
"""
from __future__ import annotations

import errno
import fcntl
import os
import select
import socket
import struct
import tempfile
import termios
import time
from pathlib import Path

__all__ = ["PtyTransport", "SocketTransport", "NoHost"]


class NoHost(OSError):
    """Nothing on the other side to take the bytes (no connection, or it stopped reading)."""


def _wait_until_empty(pending, timeout_s: float, settle_s: float = 0.02) -> bool:
    """Wait until ``pending()`` has read 0 twice, ``settle_s`` apart (the kernel moves bytes
    to the reading side asynchronously, so one 0 may come before bytes still in flight)."""
    deadline = time.monotonic() + timeout_s
    zeros = 0
    while zeros < 2:
        time.sleep(settle_s)
        zeros = zeros + 1 if pending() == 0 else 0
        if time.monotonic() > deadline:
            return False
    return True


class PtyTransport:
    """A pseudo-terminal (``os.openpty``) reached through a stable symbolic link.

    Parameters
    ----------
    link : str or Path, optional
        Path of the link the host opens (default: ``bench`` in a new temporary folder).
    write_timeout_s : float
        How long a write may wait for the host to read before :class:`NoHost`.
    """

    def __init__(self, link=None, write_timeout_s: float = 2.0):
        self.link = Path(link) if link else Path(tempfile.mkdtemp(prefix="esense-bench-")) / "bench"
        self.write_timeout_s = write_timeout_s
        self.master = self.slave = None
        self._open()

    def _open(self) -> None:
        import tty

        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: the bytes go through as they are
        os.set_blocking(master, False)
        self.master, self.slave = master, slave
        self.heard = False
        self.device = os.ttyname(slave)
        tmp = self.link.with_name(self.link.name + f".{os.getpid()}.tmp")
        tmp.unlink(missing_ok=True)
        os.symlink(self.device, tmp)
        os.replace(tmp, self.link)

    @property
    def path(self) -> str:
        return str(self.link)

    @property
    def connected(self) -> bool:
        return self.master is not None

    def write(self, data: bytes) -> None:
        if self.master is None:
            raise NoHost("the line is down")
        view = memoryview(data)
        deadline = time.monotonic() + self.write_timeout_s
        while view:
            _, ready, _ = select.select([], [self.master], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                raise NoHost("the host does not read")
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                continue
            view = view[n:]

    def read(self) -> bytes:
        if self.master is None:
            return b""
        try:
            data = os.read(self.master, 4096)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                return b""
            raise
        self.heard = self.heard or bool(data)
        return data

    def pending(self) -> int:
        """Bytes written that the host has not read yet."""
        if self.slave is None:
            return 0
        return struct.unpack("i", fcntl.ioctl(self.slave, termios.FIONREAD, b"\0\0\0\0"))[0]

    def drain(self, timeout_s: float = 2.0) -> bool:
        """Wait until the host has read everything written; False on timeout."""
        return _wait_until_empty(self.pending, timeout_s)

    def disconnect(self) -> None:
        """The port disappears: the link and the terminal are gone."""
        try:
            self.link.unlink()
        except FileNotFoundError:
            pass
        for fd in (self.master, self.slave):
            if fd is not None:
                os.close(fd)
        self.master = self.slave = None

    def reconnect(self) -> None:
        self._open()

    def close(self) -> None:
        self.disconnect()
        try:
            self.link.parent.rmdir()
        except OSError:
            pass


class SocketTransport:
    """A TCP server on loopback; the host connects with ``socket://HOST:PORT``.

    ``port=0`` picks a free port; :attr:`url` tells which.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, write_timeout_s: float = 2.0):
        self.host, self.port = host, int(port)
        self.write_timeout_s = write_timeout_s
        self.server = self.conn = None
        self.heard = False
        self._listen()

    def _listen(self) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((self.host, self.port))
        s.listen(1)
        s.setblocking(False)
        self.server = s
        self.port = s.getsockname()[1]

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    path = url

    @property
    def connected(self) -> bool:
        return self.server is not None

    def _accept(self) -> None:
        if self.server is None:
            return
        try:
            conn, _ = self.server.accept()
        except (BlockingIOError, InterruptedError):
            return
        if self.conn is not None:  # a new host replaces the old one
            self.conn.close()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(self.write_timeout_s)
        self.conn = conn
        self.heard = False

    def write(self, data: bytes) -> None:
        self._accept()
        if self.conn is None:
            raise NoHost("no host connected")
        try:
            self.conn.sendall(data)
        except OSError as exc:
            self.conn.close()
            self.conn = None
            raise NoHost(f"host gone: {exc}") from None

    def read(self) -> bytes:
        self._accept()
        if self.conn is None:
            return b""
        ready, _, _ = select.select([self.conn], [], [], 0)
        if not ready:
            return b""
        try:
            data = self.conn.recv(4096)
        except OSError:
            data = b""
        if not data:  # the host closed its side
            self.conn.close()
            self.conn = None
        self.heard = self.heard or bool(data)
        return data

    def pending(self) -> int:
        """Bytes sent that the host has not acknowledged yet."""
        if self.conn is None:
            return 0
        return struct.unpack("i", fcntl.ioctl(self.conn, termios.TIOCOUTQ, b"\0\0\0\0"))[0]

    def drain(self, timeout_s: float = 2.0) -> bool:
        """Wait until the host has received everything sent; False on timeout."""
        return _wait_until_empty(self.pending, timeout_s)

    def disconnect(self) -> None:
        for s in (self.conn, self.server):
            if s is not None:
                s.close()
        self.conn = self.server = None

    def reconnect(self) -> None:
        self._listen()

    def close(self) -> None:
        self.disconnect()
