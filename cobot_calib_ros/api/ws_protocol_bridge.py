"""The Foxglove WebSocket subprotocol under both its names, in front of foxglove-sdk's server.

foxglove-sdk 0.30.3 accepts only ``foxglove.sdk.v1`` in the handshake and answers HTTP 400 to a
client that offers only ``foxglove.websocket.v1``, the name Lichtblick and older Foxglove releases
use; the two are the same protocol under two names (foxglove/ws-protocol, lichtblick #819). This
listener takes the connections, renames the older offer in the request and the server's choice
back in the response, and passes every other byte through unchanged.
"""
from __future__ import annotations

import socket
import threading

SDK_NAME = b'foxglove.sdk.v1'
OLD_NAME = b'foxglove.websocket.v1'
HEAD_END = b'\r\n\r\n'
HEAD_LIMIT = 64 * 1024      # [bytes] an HTTP head longer than this is not a WebSocket handshake
CHUNK = 64 * 1024


def offered(head: bytes) -> list[bytes]:
    """The subprotocols a handshake request (or the one a response) names, in order."""
    names = []
    for line in head.split(b'\r\n')[1:]:
        key, _, value = line.partition(b':')
        if key.strip().lower() == b'sec-websocket-protocol':
            names += [v.strip() for v in value.split(b',') if v.strip()]
    return names


def rename(head: bytes, old: bytes, new: bytes) -> bytes:
    """``head`` with the subprotocol ``old`` named ``new`` in its Sec-WebSocket-Protocol lines."""
    lines = head.split(b'\r\n')
    for i, line in enumerate(lines[1:], 1):
        key, _, value = line.partition(b':')
        if key.strip().lower() == b'sec-websocket-protocol':
            lines[i] = key + b': ' + b', '.join(
                new if v.strip() == old else v.strip() for v in value.split(b','))
    return b'\r\n'.join(lines)


class ProtocolBridge:
    """Listens on ``host``:``port`` (0: any free port) and relays each connection to the
    server on 127.0.0.1:``target_port``. OSError if it cannot listen there."""

    def __init__(self, host: str, port: int, target_port: int) -> None:
        self.target = ('127.0.0.1', target_port)
        self._listener = socket.create_server((host, port))
        self._open: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._stopped = False
        threading.Thread(target=self._accept, name='ws_bridge', daemon=True).start()

    @property
    def port(self) -> int:
        return self._listener.getsockname()[1]

    def stop(self) -> None:
        self._stopped = True
        with self._lock:
            sockets, self._open = list(self._open) + [self._listener], set()
        for sock in sockets:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            sock.close()

    def _accept(self) -> None:
        while not self._stopped:
            try:
                client, _ = self._listener.accept()
            except OSError:             # stop() closed the listener
                return
            threading.Thread(target=self._relay, args=(client,), name='ws_bridge_conn',
                             daemon=True).start()

    def _track(self, *sockets: socket.socket) -> bool:
        with self._lock:
            if self._stopped:
                return False
            self._open.update(sockets)
            return True

    def _relay(self, client: socket.socket) -> None:
        try:
            server = socket.create_connection(self.target)
        except OSError:
            client.close()
            return
        if not self._track(client, server):
            client.close()
            server.close()
            return
        try:
            request, early = _read_head(client)
            names = offered(request)
            renamed = OLD_NAME in names and SDK_NAME not in names
            server.sendall((rename(request, OLD_NAME, SDK_NAME) if renamed else request) + early)
            response, early = _read_head(server)
            client.sendall((rename(response, SDK_NAME, OLD_NAME) if renamed else response)
                           + early)
        except OSError:
            self._close(client, server)
            return
        upstream = threading.Thread(target=_pump, args=(client, server), daemon=True)
        upstream.start()
        _pump(server, client)
        upstream.join()
        self._close(client, server)

    def _close(self, *sockets: socket.socket) -> None:
        with self._lock:
            self._open.difference_update(sockets)
        for sock in sockets:
            sock.close()


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """(the HTTP head up to its blank line, the bytes read past it). OSError if the peer
    closed first or the head is over HEAD_LIMIT."""
    data = b''
    while HEAD_END not in data:
        chunk = sock.recv(CHUNK)
        if not chunk or len(data) > HEAD_LIMIT:
            raise OSError('no complete HTTP head')
        data += chunk
    head, _, rest = data.partition(HEAD_END)
    return head + HEAD_END, rest


def _pump(source: socket.socket, sink: socket.socket) -> None:
    """Copies until ``source`` ends, then ends ``sink``'s direction."""
    try:
        while chunk := source.recv(CHUNK):
            sink.sendall(chunk)
    except OSError:
        pass
    try:
        sink.shutdown(socket.SHUT_WR)
    except OSError:
        pass
