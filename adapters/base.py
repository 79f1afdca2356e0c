"""What every adapter shares: addresses, the loopback rule, limits; and, re-exported from the
core (`streamkey.io`), the `Source` / `Sink` interfaces, their counters and the frame queue
(`streamkey.framequeue`).
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from streamkey.errors import UsageError
from streamkey.io import (
    FrameQueue,
    Sink,
    SinkStats,
    Source,
    SourceStats,
    fps_problem,
    frame_numbers_problem,
    stream_id_problem,
    stream_tag,
)

__all__ = ["Address", "parse_address", "FrameQueue", "Source", "Sink", "SourceStats",
           "SinkStats", "LOOPBACK", "bind_host", "MAX_CHANNELS",
           "MAX_MESSAGE_BYTES", "frame_numbers_problem", "fps_problem", "is_loopback",
           "stream_id_problem", "stream_tag"]

LOOPBACK = "127.0.0.1"
MAX_CHANNELS = 1024          # more channels than any skeleton we know of (CMU: 96)
MAX_MESSAGE_BYTES = 65_000   # one UDP datagram; also the ZeroMQ frame and WebSocket limit

_SCHEMES = {"osc", "zmq+tcp", "zmq+ipc", "ws", "jsonl", "-"}
_SCHEMES |= {"axis+tcp", "axis+udp", "vmc"}  # capture-system sources


@dataclass(frozen=True)
class Address:
    """A parsed `osc://host:port`, `zmq+tcp://host:port`, `ws://host:port`, `jsonl:PATH`, `-`."""

    scheme: str
    host: str = ""
    port: int = 0
    path: str = ""
    options: dict[str, str] = field(default_factory=dict)

    def __str__(self) -> str:
        if self.scheme == "-":
            return "-"
        if self.scheme == "jsonl":
            return f"jsonl:{self.path}"
        if self.scheme == "zmq+ipc":
            return f"zmq+ipc://{self.path}"
        return f"{self.scheme}://{self.host}:{self.port}"

    @property
    def zmq_endpoint(self) -> str:
        """The libzmq endpoint string (tcp://host:port or ipc://path)."""
        return f"ipc://{self.path}" if self.scheme == "zmq+ipc" else f"tcp://{self.host}:{self.port}"


def parse_address(text: str) -> Address:
    """Parse an address; raises `UsageError` naming what is wrong."""
    if text == "-":
        return Address("-")
    if text.startswith("jsonl:"):
        path = text[len("jsonl:") :]
        if not path:
            raise UsageError("jsonl: address needs a file path, e.g. jsonl:session.jsonl")
        return Address("jsonl", path=path)
    parts = urlsplit(text)
    if parts.scheme not in _SCHEMES:
        raise UsageError(f"address {text!r}: {_no_scheme(text, parts.scheme)}; expected one of "
                         "osc://HOST:PORT, zmq+tcp://HOST:PORT, ws://HOST:PORT, jsonl:PATH, -, "
                         "axis+tcp://HOST:PORT, axis+udp://HOST:PORT, vmc://HOST:PORT")
    if not text.startswith(f"{parts.scheme}://"):
        rest = text[len(parts.scheme) + 1 :].lstrip("/")
        raise UsageError(f"address {text!r}: an address needs two slashes: "
                         f"{parts.scheme}://{rest}")
    options = {k: v[-1] for k, v in parse_qs(parts.query).items()}
    if parts.scheme == "zmq+ipc":
        return Address("zmq+ipc", path=parts.netloc + parts.path, options=options)
    try:
        port = parts.port
    except ValueError:
        port = None
    if port is None:
        raise UsageError(f"address {text!r}: expected a port, e.g. {parts.scheme}://127.0.0.1:9000")
    return Address(parts.scheme, parts.hostname or LOOPBACK, port, parts.path, options)


def _no_scheme(text: str, scheme: str) -> str:
    """Why `text` has no known scheme, in the words of what it looks like: a file, a bare
    HOST:PORT, or an unknown scheme."""
    if re.fullmatch(r"[A-Za-z0-9.\-]+:\d+|\[[0-9A-Fa-f:.]+\]:\d+", text):
        return f"the scheme is missing (osc://{text}, zmq+tcp://{text}, ws://{text}, ...)"
    if "://" not in text and (not scheme or "/" in text or "\\" in text
                              or Path(text).suffix or Path(text).exists()):
        return (f"a file is not an address (for a JSON Lines file of the events write "
                f"jsonl:{text})")
    return f"unknown scheme {scheme!r}"


def is_loopback(host: str) -> bool:
    """True for `localhost` and loopback IP addresses."""
    try:
        return host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def bind_host(address: Address, listen: str | None) -> str:
    """Host a listener binds to: loopback unless `--listen` allows another interface."""
    if listen:
        return listen
    host = address.host or LOOPBACK
    if not is_loopback(host):
        raise UsageError(f"{address}: listening on {host} needs --listen {host} "
                         "(listeners bind to 127.0.0.1 by default)")
    return host
