"""What every emulated controller face shares: built from its config table, fault injection
through :meth:`simulator.servers.TcpServer.reply` and ``link_down``."""

from __future__ import annotations

import asyncio
import errno
import ipaddress
import socket

from simulator.cell import EmulatedCell
from simulator.config import ServerSection
from simulator.servers import TcpServer

#: Loopback addresses tried by ``host = "auto"`` (see :class:`simulator.config.UrRtdeSection`).
AUTO_HOSTS = tuple(f"127.0.0.{i}" for i in range(2, 255))


def _free(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as exc:
            if exc.errno != errno.EADDRINUSE:
                raise
            return False
    return True


def free_loopback_host(
    port: int, hosts: tuple[str, ...] = AUTO_HOSTS, also: tuple[int, ...] = ()
) -> str:
    """The first of ``hosts`` on which TCP ``port`` (and every port of ``also``) can be bound
    now.

    Raises ``OSError`` (EADDRINUSE) when it is taken on every one."""
    for host in hosts:
        if not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"host: {host} is not a loopback address")
        if all(_free(host, p) for p in (port, *also)):
            return host
    raise OSError(errno.EADDRINUSE, f"port {port} is taken on every address 127.0.0.2..254")


class FaceServer(TcpServer):
    """An emulated controller face on TCP, configured by its ``[robot_…]`` table.

    Subclasses implement :meth:`serve` (one client connection) and answer through
    :meth:`send` so the robot faults (drops, delays, late replies) apply; ``robot_frozen``
    applies through :meth:`simulator.cell.EmulatedCell.reported_joints`; ``link_down`` comes
    from :class:`TcpServer`.
    """

    #: Ports a face also listens on, on its own address (``host = "auto"`` picks an address
    #: where all are free): a UR's primary interface beside its RTDE port.
    also_ports: tuple[int, ...] = ()

    def __init__(self, cell: EmulatedCell, section: ServerSection) -> None:
        super().__init__(cell, section.host, section.port)
        self.section = section

    async def start(self) -> None:
        if self.host == "auto":
            # Between the probe and the bind another cell may take the address: try again.
            for _ in range(5):
                self.host = free_loopback_host(self.port, also=self.also_ports)
                try:
                    await super().start()
                    return
                except OSError as exc:
                    if exc.errno != errno.EADDRINUSE:
                        raise
                    self.host = "auto"
            raise OSError(errno.EADDRINUSE, f"no free loopback address for port {self.port}")
        await super().start()

    async def send(self, writer: asyncio.StreamWriter, data: bytes) -> None:
        """``data`` to the client under the robot faults of the cell."""
        faults = self.cell.faults
        await self.reply(
            writer,
            data,
            faults.robot_drop_rate,
            faults.robot_reply_delay_s,
            faults.robot_late_rate,
            faults.robot_late_delay_s,
        )
