"""A minimal Foxglove WebSocket protocol client on the standard library, for tests: connect,
read the advertised channels, subscribe, read message data (RFC 6455 frames, client-masked).
It offers both names of the subprotocol unless told which: Foxglove's app offers
foxglove.sdk.v1, Lichtblick and older Foxglove releases foxglove.websocket.v1 alone."""
from __future__ import annotations

import base64
import json
import os
import socket
import struct
import time

PROTOCOLS = ('foxglove.sdk.v1', 'foxglove.websocket.v1')
MESSAGE_DATA = 0x01          # binary opcode of the protocol: a message on a subscription


class FoxgloveClient:
    def __init__(self, host: str, port: int, timeout: float = 10.0,
                 protocols: tuple[str, ...] = PROTOCOLS) -> None:
        self.sock = socket.create_connection((host, port), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f'GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n'
                           f'Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n'
                           'Sec-WebSocket-Version: 13\r\n'
                           f'Sec-WebSocket-Protocol: {", ".join(protocols)}\r\n\r\n').encode())
        head = b''
        while b'\r\n\r\n' not in head:
            head += self.sock.recv(1)
        status = head.split(b'\r\n', 1)[0]
        if b' 101 ' not in status:
            raise ConnectionError(f'no WebSocket upgrade: {status!r}')
        # the subprotocol the server chose (a browser drops a connection whose choice it
        # did not offer)
        self.protocol = next((line.split(b':', 1)[1].strip().decode()
                              for line in head.split(b'\r\n')
                              if line.lower().startswith(b'sec-websocket-protocol:')), None)
        self.channels: dict[int, dict] = {}
        self.subscribed: dict[str, dict] = {}     # topic: its channel, with our subscription id

    def _exact(self, n: int) -> bytes:
        data = b''
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError('server closed the connection')
            data += chunk
        return data

    def _raw_frame(self) -> tuple[int, bytes]:
        """(first header byte, payload) of the next frame on the wire."""
        b0, b1 = self._exact(2)
        n = b1 & 0x7F
        if n == 126:
            n = struct.unpack('>H', self._exact(2))[0]
        elif n == 127:
            n = struct.unpack('>Q', self._exact(8))[0]
        return b0, self._exact(n)

    def frame(self) -> tuple[int, bytes]:
        """(opcode, payload) of the next data frame (continuations joined)."""
        opcode, payload = None, b''
        while True:
            b0, data = self._raw_frame()
            op = b0 & 0x0F
            if op in (0x9, 0xA):            # ping / pong
                continue
            opcode = op if op else opcode
            payload += data
            if b0 & 0x80:
                return opcode, payload

    def send_json(self, obj: dict) -> None:
        data, mask = json.dumps(obj).encode(), os.urandom(4)
        n = len(data)
        head = bytes([0x81]) + (bytes([0x80 | n]) if n < 126 else
                                bytes([0x80 | 126]) + struct.pack('>H', n))
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))

    def message(self, topic: str, timeout: float) -> tuple[dict, bytes]:
        """Subscribe to ``topic`` once it is advertised; (its channel, the first payload)."""
        channel, payloads = self.messages(topic, timeout, enough=1)
        return channel, payloads[0]

    def messages(self, topic: str, timeout: float, enough: int | None = None
                 ) -> tuple[dict, list[bytes]]:
        """Subscribe to ``topic`` once it is advertised (once per connection); (its channel,
        the payloads that came within ``timeout`` s, or the first ``enough`` of them).
        TimeoutError if none came."""
        payloads = self.collect(topic, timeout, enough)
        if not payloads:
            raise TimeoutError(f'no message on {topic} within {timeout} s '
                               f'(advertised: {[c["topic"] for c in self.channels.values()]})')
        return self.subscribed[topic], payloads

    def collect(self, topic: str, timeout: float, enough: int | None = None) -> list[bytes]:
        """:meth:`messages`' payloads, [] if none came."""
        deadline, payloads = time.monotonic() + timeout, []
        while time.monotonic() < deadline and (enough is None or len(payloads) < enough):
            self.sock.settimeout(max(0.1, deadline - time.monotonic()))
            try:
                opcode, payload = self.frame()
            except TimeoutError:
                break
            if opcode == 0x1:
                msg = json.loads(payload)
                if msg.get('op') == 'advertise':
                    for channel in msg['channels']:
                        self.channels[channel['id']] = channel
                        if channel['topic'] == topic and topic not in self.subscribed:
                            self._subscribe(channel)
            elif opcode == 0x2 and payload[0] == MESSAGE_DATA and topic in self.subscribed:
                subscription, _stamp = struct.unpack('<IQ', payload[1:13])
                if subscription == self.subscribed[topic]['subscription']:
                    payloads.append(payload[13:])
        return payloads

    def _subscribe(self, channel: dict) -> None:
        number = len(self.subscribed) + 1
        self.subscribed[channel['topic']] = {**channel, 'subscription': number}
        self.send_json({'op': 'subscribe', 'subscriptions': [
            {'id': number, 'channelId': channel['id']}]})

    def close(self) -> None:
        """The closing handshake, as a browser closing its window does (RFC 6455 5.5.1): a
        close frame, the server's close frame back (at most 1 s), then the socket. A bare
        socket close is a reset to the server ('Connection reset without closing handshake'),
        and a second window connecting while the server handled one got no latched message
        in 2 of ~12 runs."""
        try:
            mask, status = os.urandom(4), struct.pack('>H', 1000)     # 1000: normal closure
            self.sock.sendall(bytes([0x88, 0x80 | len(status)]) + mask
                              + bytes(b ^ mask[i % 4] for i, b in enumerate(status)))
            self.sock.settimeout(1.0)
            while self._raw_frame()[0] & 0x0F != 0x8:
                pass
        except (OSError, ConnectionError):
            pass
        finally:
            self.sock.close()
