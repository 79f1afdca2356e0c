"""WebSocket server sink: every event as JSON text to every connected client.

Broadcast is O(1) on the frame path: a message is serialised once and appended to one
shared ring; each client's sender task follows the ring with its own cursor. After the
frame's work, one fan-out task wakes the senders `FANOUT_CHUNK` at a time, one chunk per
loop turn, so a frame arriving meanwhile waits for a chunk of sends, not for all of them.
A client that falls more than the ring's length behind loses its oldest messages
(counted), never slowing the engine or other clients (websockets' `broadcast()` has no
backpressure). Compression is off.

Who may connect (the same rules as the dashboard): the server binds to loopback unless
`listen` says otherwise; on loopback only the host names 127.0.0.1, localhost and [::1] are
answered (no DNS rebinding); a browser's `Origin` must be the server's own
(`http://` + Host), so a web page open in the operator's browser cannot read the events;
listening beyond loopback needs a token (`?token=...` in the URL, printed at start).
Refusals are counted by kind with a small ring of recent reasons; they never end a
connection that was accepted. Messages from clients go to an optional `on_message`
callback, whose reply (if any) is sent back to that client only; a callback that fails
gets an error reply, the connection stays open.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import secrets
import socket
from collections import Counter, deque
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed

from streamkey.errors import InputError
from streamkey.keyframes import Event

from .base import MAX_MESSAGE_BYTES, Address, Sink, bind_host
from .codec import event_json, record_json

__all__ = ["WebSocketSink", "Client", "CLIENT_QUEUE", "LOOPBACK_NAMES", "RECENT_REFUSALS"]

CLIENT_QUEUE = 256          # messages a client may fall behind before it loses the oldest
RECENT_REFUSALS = 20        # refusal reasons kept (counters keep the totals)
FANOUT_CHUNK = 16           # client senders woken per loop turn
LOOPBACK_NAMES = {"127.0.0.1", "localhost", "::1", "[::1]"}


class Client:
    """One connected client: its connection, its cursor in the shared ring, its replies."""

    def __init__(self, connection: ServerConnection, cursor: int) -> None:
        self.connection = connection
        self.cursor = cursor      # seq of the last broadcast message handed to this client
        self.replies: deque[str] = deque(maxlen=64)
        self.dropped = 0
        self.wake = asyncio.Event()

    def put(self, text: str) -> None:
        """Queue a message for this client only (a reply or the greeting)."""
        if len(self.replies) == self.replies.maxlen:
            self.dropped += 1
        self.replies.append(text)
        self.wake.set()


class WebSocketSink(Sink):
    """Broadcast events (JSON) to every client of a WebSocket server bound to loopback."""

    name = "ws"

    def __init__(self, address: Address, listen: str | None = None,
                 on_message: Callable[[str], dict[str, Any] | None] | None = None,
                 client_queue: int = CLIENT_QUEUE, send_buffer: int = 65536,
                 token: str | None = None) -> None:
        super().__init__()
        self.client_queue = client_queue
        self.send_buffer = send_buffer
        self.address = address
        self.host = bind_host(address, listen)
        self.loopback = self.host in LOOPBACK_NAMES
        self.token = token if token is not None else (None if self.loopback
                                                      else secrets.token_urlsafe(16))
        self.on_message = on_message
        self.clients: set[Client] = set()
        self.server: Server | None = None
        self.client_drops = 0
        self.ring: deque[str] = deque(maxlen=client_queue)
        self.ring_seq = 0
        self._fanout_pending = False
        self._fanout: asyncio.Task[None] | None = None
        self.refused: deque[str] = deque(maxlen=RECENT_REFUSALS)
        self.refusals: Counter[str] = Counter()

    async def start(self) -> str:
        self.ring = deque(maxlen=self.client_queue)
        try:
            self.server = await self._serve()
        except OSError as exc:
            raise InputError(f"{self.address}: cannot listen on {self.host}:"
                             f"{self.address.port}: {exc.strerror or exc}") from None
        query = f"/?token={self.token}" if self.token else ""
        return f"ws://{self.host}:{self.port}{query}"

    async def _serve(self) -> Server:
        return await serve(self._handle, self.host, self.address.port, compression=None,
                           max_size=MAX_MESSAGE_BYTES, process_request=self._http,
                           ping_interval=5, ping_timeout=10, write_limit=4096, close_timeout=1)

    @property
    def port(self) -> int:
        """The bound port (useful when the address asked for port 0)."""
        assert self.server is not None
        return int(self.server.sockets[0].getsockname()[1])

    # ------------------------------------------------------------------ who may connect
    def _http(self, connection: Any, request: Any) -> Any:
        """Only WebSocket upgrades from an allowed host, origin and token."""
        why = self.host_problem(request) or self.origin_problem(request)
        if why is None and not self.token_ok(request):
            why = ("token", "WebSocket refused: missing or wrong token")
        return None if why is None else self.refuse(connection, *why)

    def host_problem(self, request: Any) -> tuple[str, str] | None:
        """(kind, reason) if the Host header is not ours on loopback (DNS rebinding), or
        Host / Origin appear more than once."""
        for name in ("Host", "Origin"):
            if len(request.headers.get_all(name)) > 1:
                return ("header", f"refused: more than one {name} header")
        host = request.headers.get("Host", "")
        try:
            hostname = urlsplit(f"//{host}").hostname or ""
        except ValueError:
            hostname = ""
        if self.loopback and hostname not in LOOPBACK_NAMES:
            return ("host", f"host {host[:80]!r} refused: this server answers to "
                            "127.0.0.1 / localhost only")
        return None

    def origin_problem(self, request: Any) -> tuple[str, str] | None:
        """(kind, reason) if a browser's Origin is not this server's own."""
        host = request.headers.get("Host", "")
        origin = request.headers.get("Origin")
        if origin is not None and origin != f"http://{host}":
            return ("origin", f"cross-origin WebSocket refused: origin {origin[:80]} is not "
                              f"http://{host[:80]}")
        return None

    def token_ok(self, request: Any) -> bool:
        """True if no token is needed or the request's `?token=` matches (constant time)."""
        if self.token is None:
            return True
        try:
            token = parse_qs(urlsplit(request.path).query).get("token", [""])[-1]
        except ValueError:
            return False
        return hmac.compare_digest(token.encode("utf-8", "replace"), self.token.encode())

    def refuse(self, connection: Any, kind: str, why: str) -> Any:
        """Answer 403 with the reason; count it (bounded memory whatever the number)."""
        self.refusals[kind] += 1
        self.refused.append(why[:300])
        return connection.respond(403, why + "\n")

    # ------------------------------------------------------------------ connections
    async def _handle(self, connection: ServerConnection) -> None:
        client = Client(connection, self.ring_seq)
        sock = connection.transport.get_extra_info("socket")
        if sock is not None:  # a small kernel buffer: a stalled client shows up in seconds
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.send_buffer)
        greeting = self.greeting()
        if greeting is not None:
            client.put(json.dumps(greeting, separators=(",", ":")))
        self.clients.add(client)
        sender = asyncio.create_task(self._send_loop(client))
        try:
            async for message in connection:
                self._reply(client, message)
        except ConnectionClosed:
            pass
        finally:
            sender.cancel()
            self.clients.discard(client)
            lag = self.ring_seq - client.cursor  # broadcast but never handed to this client
            client.dropped += lag
            self.stats.dropped += lag
            self.client_drops += client.dropped

    def greeting(self) -> dict[str, Any] | None:
        """First message to every new client (none here; the dashboard sends its state)."""
        return None

    def _reply(self, client: Client, message: str | bytes) -> None:
        if self.on_message is None:
            return
        text = message if isinstance(message, str) else message.decode("utf-8", "replace")
        try:
            reply = self.on_message(text)
        except Exception as exc:  # a refusal, never a 1011 close
            self.refusals["message"] += 1
            reply = {"type": "error", "id": None,
                     "error": f"message refused: {type(exc).__name__}"}
        if reply is not None:
            client.put(json.dumps(reply))

    async def _send_loop(self, client: Client) -> None:
        try:
            while True:
                while client.replies:
                    await client.connection.send(client.replies.popleft())
                if client.cursor == self.ring_seq:
                    client.wake.clear()
                    await client.wake.wait()
                    continue
                oldest = self.ring_seq - len(self.ring) + 1
                if client.cursor + 1 < oldest:  # fell behind the ring: its oldest are gone
                    lost = oldest - client.cursor - 1
                    client.dropped += lost
                    self.stats.dropped += lost
                    client.cursor = oldest - 1
                client.cursor += 1
                await client.connection.send(self.ring[client.cursor - oldest])
        except ConnectionClosed:
            pass

    def offer(self, event: Event) -> None:
        self._broadcast_text(event_json(event))

    def broadcast(self, message: dict[str, Any]) -> None:
        """Serialise once and append to the shared ring: O(1) whatever the number of clients;
        the clients' senders are woken once, after the current loop turn."""
        self._broadcast_text(record_json(message))

    def _broadcast_text(self, text: str) -> None:
        self.ring.append(text)
        self.ring_seq += 1
        self.stats.sent += 1
        self._notify()

    def _notify(self) -> None:
        if not self._fanout_pending and self.clients:
            self._fanout_pending = True
            self._fanout = asyncio.get_running_loop().create_task(self._fan_out())

    async def _fan_out(self) -> None:
        """Wake the clients' senders a chunk per loop turn, so a frame that arrives in the
        meantime waits for one chunk of sends, not for every client's."""
        await asyncio.sleep(0)  # after the current frame's work
        self._fanout_pending = False  # a broadcast from now on schedules another pass
        for i, client in enumerate(list(self.clients)):
            client.wake.set()
            if i % FANOUT_CHUNK == FANOUT_CHUNK - 1:
                await asyncio.sleep(0)

    def _behind(self, client: Client) -> bool:
        return bool(client.replies) or client.cursor < self.ring_seq

    async def close(self) -> None:
        deadline = asyncio.get_running_loop().time() + 1.0
        while any(self._behind(c) for c in self.clients):
            if asyncio.get_running_loop().time() > deadline:
                break
            await asyncio.sleep(0.01)
        for client in list(self.clients):
            transport = client.connection.transport
            if self._behind(client) or transport.get_write_buffer_size():
                transport.abort()  # a stalled reader would hold the close up; its lag
                # is counted when its handler ends
        if self.server is not None:
            self.server.close()
            await self.server.wait_closed()
