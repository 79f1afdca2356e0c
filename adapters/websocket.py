"""WebSocket server sink: every event as JSON text to every connected client.

Each client has its own bounded queue and sender task: a client that stops reading fills its
own queue and loses its oldest events (counted), never slowing the engine or other clients
(websockets' `broadcast()` has no backpressure, notes/ecosystem.md). Compression is off.
Messages from clients go to an optional `on_message` callback, whose reply (if any) is sent
back to that client only.
"""

from __future__ import annotations

import asyncio
import json
import socket
from collections.abc import Callable
from typing import Any

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed

from streamkey.errors import InputError
from streamkey.keyframes import Event

from .base import MAX_MESSAGE_BYTES, Address, Sink, bind_host, put_drop_oldest

__all__ = ["WebSocketSink", "Client", "CLIENT_QUEUE"]

CLIENT_QUEUE = 256


class Client:
    """One connected client: its connection and bounded outgoing queue."""

    def __init__(self, connection: ServerConnection, size: int) -> None:
        self.connection = connection
        self.queue: asyncio.Queue[str] = asyncio.Queue(size)
        self.dropped = 0

    def put(self, text: str) -> None:
        """Queue a message for this client, dropping its oldest when full."""
        self.dropped += put_drop_oldest(self.queue, text)


class WebSocketSink(Sink):
    """Broadcast events (JSON) to every client of a WebSocket server bound to loopback."""

    name = "ws"

    def __init__(self, address: Address, listen: str | None = None,
                 on_message: Callable[[str], dict[str, Any] | None] | None = None,
                 origins: list[str | None] | None = None,
                 client_queue: int = CLIENT_QUEUE, send_buffer: int = 65536) -> None:
        super().__init__()
        self.client_queue = client_queue
        self.send_buffer = send_buffer
        self.address = address
        self.host = bind_host(address, listen)
        self.on_message = on_message
        self.origins = origins
        self.clients: set[Client] = set()
        self.server: Server | None = None
        self.client_drops = 0

    async def start(self) -> str:
        try:
            self.server = await self._serve()
        except OSError as exc:
            raise InputError(f"{self.address}: cannot listen on {self.host}:"
                             f"{self.address.port}: {exc.strerror or exc}") from None
        port = self.server.sockets[0].getsockname()[1]
        return f"ws://{self.host}:{port}"

    async def _serve(self) -> Server:
        return await serve(self._handle, self.host, self.address.port, compression=None,
                           max_size=MAX_MESSAGE_BYTES, origins=self.origins, ping_interval=5,
                           ping_timeout=10, write_limit=4096, close_timeout=1)

    @property
    def port(self) -> int:
        """The bound port (useful when the address asked for port 0)."""
        assert self.server is not None
        return int(self.server.sockets[0].getsockname()[1])

    async def _handle(self, connection: ServerConnection) -> None:
        client = Client(connection, self.client_queue)
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
            self.client_drops += client.dropped

    def greeting(self) -> dict[str, Any] | None:
        """First message to every new client (none here; the dashboard sends its state)."""
        return None

    def _reply(self, client: Client, message: str | bytes) -> None:
        if self.on_message is None:
            return
        text = message if isinstance(message, str) else message.decode("utf-8", "replace")
        reply = self.on_message(text)
        if reply is not None:
            client.put(json.dumps(reply))

    async def _send_loop(self, client: Client) -> None:
        try:
            while True:
                await client.connection.send(await client.queue.get())
        except ConnectionClosed:
            pass

    def offer(self, event: Event) -> None:
        self.broadcast(event.to_dict())

    def broadcast(self, message: dict[str, Any]) -> None:
        """Queue one JSON message for every client (drop-oldest per client, counted)."""
        text = json.dumps(message, separators=(",", ":"))
        for client in list(self.clients):
            before = client.dropped
            client.put(text)
            self.stats.dropped += client.dropped - before
        self.stats.sent += 1

    async def close(self) -> None:
        deadline = asyncio.get_running_loop().time() + 1.0
        while any(not c.queue.empty() for c in self.clients):
            if asyncio.get_running_loop().time() > deadline:
                break
            await asyncio.sleep(0.01)
        for client in list(self.clients):
            transport = client.connection.transport
            if not client.queue.empty() or transport.get_write_buffer_size():
                transport.abort()  # a stalled reader would hold the close handshake up
        if self.server is not None:
            self.server.close()
            await self.server.wait_closed()
