"""EMULATED KukaVarProxy (OpenShowVar protocol) serving the emulated cell's robot.

Speaks the frames of :mod:`drivers.kuka_varproxy` as the real proxy does (ImtsSrl
KUKAVARPROXY ``readMsg``): the reply echoes the request's message id, its ``length`` counts
the 3-byte tail ``00 01 status``, requests are answered in order (several may arrive in one
TCP segment). Variables:

``$AXIS_ACT``, ``$AXIS_ACT_MEAS``
    ``{E6AXIS: A1 …, A6 …, E1 0.0, …}``: the cell's reported joints [deg] (frozen while the
    ``robot_frozen`` fault is on), 7 significant digits as KRL prints a ``REAL``. Read-only.
    (On a controller the first is the commanded, the second the measured position; at a fine
    stop they agree to the servo error, which the emulation does not model.)
``$OV_PRO``
    Program override [%], ``100`` at start; a write of an integer 0..100 is kept.
``$MODE_OP``, ``$ROBNAME[]``
    ``#EX`` and ``"EMULATED KR"``; read-only.
``PING``
    ``PONG`` (the proxy's keep-alive).

Any other variable reads as an empty value with status 1, as the proxy answers when
CrossComm's ``ShowVar`` fails (drivers treat it as an error); a write to a read-only or
unknown variable echoes the value with status 0. A frame whose lengths do not add up closes
the connection. The robot fault settings (drops, delays, late replies) apply to every reply.
The real proxy has no credentials and neither has this.
"""

from __future__ import annotations

import asyncio
import logging

from drivers.kuka_varproxy import (
    FUNCTION_READ,
    FUNCTION_WRITE,
    encode_reply,
    format_e6axis,
    split_request,
)
from simulator.cell import EmulatedCell
from simulator.config import ServerSection
from simulator.faces.base import FaceServer

log = logging.getLogger("cablecal.simulator")

#: Read-only variables other than $AXIS_ACT, with their values.
FIXED_VARIABLES = {"$MODE_OP": "#EX", "$ROBNAME[]": '"EMULATED KR"', "PING": "PONG"}


class KukaVarProxyServer(FaceServer):
    """EMULATED KukaVarProxy on TCP (the real one listens on 7000), ``[robot_kuka_varproxy]``."""

    label = "kuka-varproxy"

    def __init__(self, cell: EmulatedCell, section: ServerSection) -> None:
        super().__init__(cell, section)
        self.override_pct = 100
        #: Requests answered or dropped since start [count].
        self.requests = 0

    def read_variable(self, name: str) -> str | None:
        """The value string of ``name``, or None for an unknown variable."""
        key = name.upper()
        if key in ("$AXIS_ACT", "$AXIS_ACT_MEAS"):
            return format_e6axis([float(v) for v in self.cell.reported_joints()])
        if key == "$OV_PRO":
            return str(self.override_pct)
        return FIXED_VARIABLES.get(key)

    def write_variable(self, name: str, value: str) -> bool:
        """Write ``value`` to ``name``; False when refused (read-only, unknown, bad value)."""
        if name.upper() != "$OV_PRO":
            return False
        try:
            pct = int(value.strip())
        except ValueError:
            return False
        if not 0 <= pct <= 100:
            return False
        self.override_pct = pct
        return True

    def answer(self, msg_id: int, function: int, name: str, value: str | None) -> bytes:
        """The reply frame to one request."""
        if function == FUNCTION_WRITE and value is not None:
            ok = self.write_variable(name, value)
            return encode_reply(msg_id, function, value.encode("ascii"), ok)
        if function == FUNCTION_READ:
            text = self.read_variable(name)
            return encode_reply(msg_id, function, (text or "").encode("ascii"), True)
        return encode_reply(msg_id, function, b"", False)  # a function this emulation lacks

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        buf = b""
        while data := await reader.read(4096):
            buf += data
            while True:
                used, request = split_request(buf)
                if used == 0:
                    break
                buf = buf[used:]
                if request is None:
                    log.debug("kuka-varproxy: malformed request; connection closed")
                    return
                self.requests += 1
                await self.send(writer, self.answer(*request))
