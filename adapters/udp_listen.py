"""One UDP listener for the datagram sources (Axis over UDP, VMC): bind, hand each datagram
to a callback on the event loop, name the bound address for the ready line."""

from __future__ import annotations

import asyncio
import os
import socket
from collections.abc import Callable
from typing import Any

from streamkey.errors import InputError
from streamkey.motion import Skeleton

from .base import Address, Source, SourceStats

__all__ = ["listen_udp", "proc_udp_drops", "refresh_kernel_drops", "DatagramSource"]


def proc_udp_drops(sock: socket.socket) -> int | None:
    """The `drops` column of /proc/net/udp for this socket (Linux), else None."""
    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
        with open("/proc/net/udp", encoding="ascii") as table:
            for line in table:
                fields = line.split()
                if len(fields) >= 13 and fields[9] == inode:
                    return int(fields[12])
    except (OSError, ValueError):
        return None
    return None


def refresh_kernel_drops(stats: SourceStats, sock: socket.socket | None) -> SourceStats:
    """`stats` with the kernel's receive-buffer drops of `sock` (none known: unchanged)."""
    if sock is not None and sock.fileno() >= 0:
        drops = proc_udp_drops(sock)
        if drops is not None:
            stats.kernel_drops = max(stats.kernel_drops or 0, drops)
    return stats


async def listen_udp(address: Address, host: str, receive: Callable[[bytes], None]
                     ) -> tuple[asyncio.DatagramTransport, int]:
    """Bind `host:address.port` (0: any free port); returns the transport and the bound port."""

    class Protocol(asyncio.DatagramProtocol):
        def datagram_received(self, data: bytes, addr: Any) -> None:
            receive(data)

    loop = asyncio.get_running_loop()
    try:
        transport, _ = await loop.create_datagram_endpoint(
            Protocol, local_addr=(host, address.port), family=socket.AF_INET)
    except OSError as exc:
        raise InputError(f"{address}: cannot listen on {host}:{address.port}: "
                         f"{exc.strerror or exc}") from None
    sock = transport.get_extra_info("socket")
    try:  # room for a burst while the keyframers are busy (the kernel may cap it)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    except OSError:
        pass
    return transport, int(transport.get_extra_info("sockname")[1])


class DatagramSource(Source):
    """Base of the vendor sources that listen on UDP (Axis, VMC): the address, a skeleton
    (the rig's built-in one unless given), the transport, and kernel drops in the counters."""

    def __init__(self, address: Address, skeleton: Skeleton, fps: float | None) -> None:
        super().__init__(skeleton, fps or 60.0)
        self.address = address
        self.transport: asyncio.DatagramTransport | None = None

    async def listen(self, host: str, receive: Callable[[bytes], None]) -> int:
        """Bind the listener; returns the bound port."""
        self.transport, port = await listen_udp(self.address, host, receive)
        return port

    def counters(self) -> SourceStats:
        """Counters, with the kernel's receive-buffer drops of the listening socket."""
        sock = self.transport.get_extra_info("socket") if self.transport is not None else None
        return refresh_kernel_drops(self.stats, sock)

    async def close(self) -> None:
        self.counters()
        await super().close()
        if self.transport is not None:
            self.transport.close()
