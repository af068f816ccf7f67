"""A TCP relay in front of a WebSocket server that accepts a second name for its subprotocol.

The Foxglove WebSocket protocol is spoken under two subprotocol names:
``foxglove.websocket.v1``, which the open-source clients ask for
(``@foxglove/ws-protocol``, Lichtblick, older Foxglove releases), and
``foxglove.sdk.v1``, the only one ``foxglove-sdk`` (0.30) accepts. The two
are the same protocol under two names (Foxglove's stated position, and why
Lichtblick merely added the new name). So the live view keeps ``foxglove-sdk``
behind this relay: it reads each connection's HTTP upgrade request, renames
an asked-for old name to the new one, passes the request on to the server,
renames the server's answer back, and from then on copies bytes both ways
unchanged. A client that asks for the new name passes through as it is.

ROS-free, stdlib only: a listening socket and two threads per connection.
"""

from __future__ import annotations

import socket
import threading
import time

__all__ = ["SubprotocolRelay"]

_HEADER = b"sec-websocket-protocol:"
_MAX_HEAD = 65536


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """An HTTP message's head (to the blank line) and the bytes after it; empty head on EOF or an oversize one."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk or len(data) > _MAX_HEAD:
            return b"", b""
        data += chunk
    head, _, rest = data.partition(b"\r\n\r\n")
    return head + b"\r\n\r\n", rest


def _rename(head: bytes, renames: dict[bytes, bytes]) -> tuple[bytes, dict[bytes, bytes]]:
    """``head`` with the subprotocol names of ``renames`` replaced in its Sec-WebSocket-Protocol line(s).

    Returns the new head and the renames applied (new name -> the name the client asked for).
    """
    lines = head.split(b"\r\n")
    applied: dict[bytes, bytes] = {}
    for i, line in enumerate(lines):
        if line.lower().startswith(_HEADER):
            name, _, value = line.partition(b":")
            offered = [v.strip() for v in value.split(b",") if v.strip()]
            if any(new in offered for new in renames.values()):
                continue  # the client speaks the server's name already
            out = []
            for v in offered:
                if v in renames:
                    applied[renames[v]] = v
                    v = renames[v]
                out.append(v)
            lines[i] = name + b": " + b", ".join(out)
    return b"\r\n".join(lines), applied


class SubprotocolRelay:
    """Listen on ``host:port`` and relay every connection to ``127.0.0.1:target_port``, renaming subprotocols.

    Parameters
    ----------
    host, port : str, int
        Where clients connect.
    target_port : int
        The WebSocket server's port on this machine.
    renames : dict of str
        Subprotocol name a client may ask for -> the name the server speaks.

    Raises
    ------
    OSError
        The address cannot be listened on.
    """

    def __init__(self, host: str, port: int, target_port: int, renames: dict[str, str]) -> None:
        self.target_port = target_port
        self.renames = {k.encode(): v.encode() for k, v in renames.items()}
        info = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        self._listener = socket.socket(info[0], info[1], info[2])
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind(info[4])
        self._listener.listen(16)
        self.port = self._listener.getsockname()[1]
        self._closed = threading.Event()
        self._connections: set[socket.socket] = set()
        self._workers: list[threading.Thread] = []
        self._lock = threading.Lock()
        threading.Thread(target=self._accept, name="foxglove-relay", daemon=True).start()

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                client, _ = self._listener.accept()
            except OSError:
                return  # closed
            worker = threading.Thread(target=self._serve, args=(client,), daemon=True)
            with self._lock:
                self._workers.append(worker)
            worker.start()

    def _serve(self, client: socket.socket) -> None:
        server = None
        try:
            head, rest = _read_head(client)
            if not head:
                return
            head, applied = _rename(head, self.renames)
            server = socket.create_connection(("127.0.0.1", self.target_port))
            with self._lock:
                self._connections.update((client, server))
            server.sendall(head + rest)
            answer, rest = _read_head(server)
            if not answer:
                return
            client.sendall(_rename(answer, applied)[0] + rest)
            pump = threading.Thread(target=self._copy, args=(server, client), daemon=True)
            pump.start()
            self._copy(client, server)
            pump.join()
        except OSError:
            pass  # a client or the server went away: the connection ends
        finally:
            for sock in (client, server):
                if sock is not None:
                    with self._lock:
                        self._connections.discard(sock)
                    sock.close()

    @staticmethod
    def _copy(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        finally:
            try:
                dst.shutdown(socket.SHUT_WR)  # the other side sees the end of this direction
            except OSError:
                pass

    def close(self, drain_s: float = 0.0) -> None:
        """Stop listening and end every relayed connection (idempotent).

        ``drain_s``: how long (s) connections may take to end by themselves first, each forwarding what
        the server sent before it closed (close the server, then the relay, and clients get it all).
        """
        self._closed.set()
        self._listener.close()
        deadline = time.monotonic() + drain_s
        with self._lock:
            workers = list(self._workers)
        for worker in workers:
            worker.join(timeout=max(deadline - time.monotonic(), 0.0))
        with self._lock:
            connections = list(self._connections)
        for sock in connections:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
