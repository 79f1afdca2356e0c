"""Live keypose markers: events of a running `streamkey run` turned into timeline markers.

`MarkerBook` is the bookkeeping without Blender: a provisional event adds a marker named
`method? strength`, its confirming keyframe event replaces it by `method strength`, a cancel
removes it. Receivers poll without blocking (Blender calls them from a timer): `ZmqReceiver`
subscribes to the events a `--to zmq+tcp://HOST:PORT` sink publishes, `OscReceiver` binds the
UDP port a `--to osc://HOST:PORT` sink sends to (numeric or compact layout).
"""

from __future__ import annotations

import json
import socket
from dataclasses import dataclass, field
from typing import Any, Protocol
from urllib.parse import urlsplit

from .keys import marker_name

__all__ = ["MarkerBook", "ZmqReceiver", "OscReceiver", "make_receiver", "ListenError",
           "MarkerStore"]


class ListenError(ConnectionError):
    """The address is malformed, or nothing is publishing there (the message says which)."""


class MarkerStore(Protocol):
    """What `MarkerBook` needs of `scene.timeline_markers`."""

    def new(self, name: str, frame: int = ...) -> Any: ...  # noqa: D102

    def remove(self, marker: Any) -> None: ...  # noqa: D102


@dataclass
class MarkerBook:
    """Markers placed for live events: provisional ones by (stream, method, pid)."""

    offset: int = 1
    provisional: dict[tuple[str, str, int], Any] = field(default_factory=dict)
    confirmed: int = 0
    cancelled: int = 0

    def apply(self, store: MarkerStore, event: dict[str, Any]) -> None:
        """Place, replace or remove markers for one event (other event kinds ignored)."""
        kind = event.get("type")
        stream, method = str(event.get("stream", "default")), str(event.get("method", "?"))
        if kind == "provisional":
            key = (stream, method, int(event.get("pid", event.get("frame", -1))))
            self._drop(store, key)
            self.provisional[key] = store.new(
                marker_name(method, float(event.get("strength", 1.0)), provisional=True),
                frame=self.offset + int(event["frame"]))
        elif kind == "cancel":
            self._drop(store, (stream, method, int(event.get("pid", event.get("frame", -1)))))
            self.cancelled += 1
        elif kind == "keyframe":
            pid = event.get("confirms")
            self._drop(store, (stream, method, int(event["frame"] if pid is None else pid)))
            store.new(marker_name(method, float(event.get("strength", 1.0))),
                      frame=self.offset + int(event["frame"]))
            self.confirmed += 1

    def _drop(self, store: MarkerStore, key: tuple[str, str, int]) -> None:
        marker = self.provisional.pop(key, None)
        if marker is not None:
            store.remove(marker)

    def clear_provisional(self, store: MarkerStore) -> None:
        """Remove the provisional markers still waiting (on stop)."""
        for key in list(self.provisional):
            self._drop(store, key)


def _host_port(address: str, schemes: tuple[str, ...]) -> tuple[str, int]:
    parts = urlsplit(address)
    if parts.scheme not in schemes or not parts.hostname or parts.port is None:
        raise ListenError(f"address {address!r}: expected {schemes[0]}://HOST:PORT")
    return parts.hostname, parts.port


class ZmqReceiver:
    """SUB socket connected to a `streamkey run --to zmq+tcp://HOST:PORT` publisher."""

    def __init__(self, address: str) -> None:
        import zmq

        host, port = _host_port(address, ("zmq+tcp", "tcp"))
        try:  # a SUB socket connects to nothing without complaint: ask the port first
            socket.create_connection((host, port), timeout=1.0).close()
        except OSError as exc:
            raise ListenError(f"nothing listening at {address} ({exc.strerror or exc}): start"
                              f" `streamkey run ... --to zmq+tcp://{host}:{port}` first") from exc
        self.address = address
        self.socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.SUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.SUBSCRIBE, b"event")
        self.socket.connect(f"tcp://{host}:{port}")
        self._zmq = zmq
        self.rejected = 0

    def poll(self, limit: int = 1000) -> list[dict[str, Any]]:
        """The events that arrived since the last call (never blocks)."""
        out: list[dict[str, Any]] = []
        for _ in range(limit):
            try:
                parts = self.socket.recv_multipart(self._zmq.NOBLOCK)
            except self._zmq.Again:
                break
            try:
                event = json.loads(parts[1])
            except (IndexError, ValueError):
                self.rejected += 1
                continue
            if isinstance(event, dict):
                out.append(event)
        return out

    def close(self) -> None:
        """Close the socket."""
        self.socket.close()


class OscReceiver:
    """UDP socket bound where `streamkey run --to osc://HOST:PORT` sends its messages."""

    def __init__(self, address: str) -> None:
        host, port = _host_port(address, ("osc", "udp"))
        self.address = address
        self.socket: socket.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.socket.bind((host, port))
        except OSError as exc:
            self.socket.close()
            raise ListenError(f"cannot listen at {address}: {exc.strerror or exc}") from exc
        self.socket.setblocking(False)
        self.rejected = 0

    def poll(self, limit: int = 1000) -> list[dict[str, Any]]:
        """The events in the datagrams that arrived since the last call (never blocks)."""
        from pythonosc.osc_packet import OscPacket, ParseError

        out: list[dict[str, Any]] = []
        for _ in range(limit):
            try:
                data = self.socket.recv(65536)
            except BlockingIOError:
                break
            try:
                messages = [t.message for t in OscPacket(data).messages]
            except ParseError:
                self.rejected += 1
                continue
            out += [e for m in messages if (e := osc_event(m.address, list(m.params)))]
        return out

    def close(self) -> None:
        """Close the socket."""
        self.socket.close()


def osc_event(address: str, args: list[Any]) -> dict[str, Any] | None:
    """The event dict of one OSC message (numeric or compact layout), None for others."""
    parts = address.strip("/").split("/")
    try:
        if parts == ["streamkey", "keyframe"]:  # compact: stream, method, frame, time, score, lat
            return {"type": "keyframe", "stream": args[0], "method": args[1],
                    "frame": int(args[2]), "strength": 1.0}
        if len(parts) == 4 and parts[0] == "streamkey":
            _, stream, method, kind = parts
            if kind == "keyframe":
                return {"type": kind, "stream": stream, "method": method, "frame": int(args[0]),
                        "strength": float(args[2])}
            if kind == "provisional":
                return {"type": kind, "stream": stream, "method": method, "frame": int(args[0]),
                        "strength": float(args[2])}
            if kind == "cancel":
                return {"type": kind, "stream": stream, "method": method, "frame": int(args[0])}
    except (IndexError, TypeError, ValueError):
        return None
    return None


def make_receiver(address: str) -> ZmqReceiver | OscReceiver:
    """The receiver for a `zmq+tcp://` or `osc://` address."""
    if address.startswith(("zmq+tcp://", "tcp://")):
        return ZmqReceiver(address)
    if address.startswith(("osc://", "udp://")):
        return OscReceiver(address)
    raise ListenError(f"address {address!r}: expected zmq+tcp://HOST:PORT or osc://HOST:PORT")
