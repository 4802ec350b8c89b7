"""EMULATED ABB Robot Web Services face: the joints of the cell's robot as an IRC5 (RWS 1.0)
or an OmniCore (RWS 2.0) controller serves them.

- **RWS 1.0** (``rws = "1.0"``, IRC5): HTTP, digest authentication (RFC 7616 with
  ``qop=auth``, MD5, realm ``validusers@robapi.abb``); after a successful login the
  controller sets the session cookies ``-http-session-`` and ``ABBCX`` and accepts them in
  place of credentials. ``?json=1`` answers ``application/json`` with the state under
  ``_embedded._state``; without it, ``application/xhtml+xml`` (``<li class=...>`` with
  ``<span class=...>`` values).
- **RWS 2.0** (``rws = "2.0"``, OmniCore): HTTPS (TLS with ``cert_file``/``key_file``; when
  unset, a self-signed certificate generated at start with the ``openssl`` command), basic
  authentication, then the same cookies; ``Accept: application/hal+json;v=2.0`` answers HAL
  JSON with the state under ``state``, otherwise ``application/xhtml+xml;v=2.0``.

Resources: ``GET /rw/motionsystem/mechunits/ROB_1/jointtarget`` (``ms-jointtarget``: ``rax_1``
… ``rax_6`` [deg], six decimals; ``eax_a`` … ``eax_f`` ``9E+09``, no external axes),
``GET /rw/motionsystem/mechunits/ROB_1/robtarget`` (hook point [mm], flange quaternion,
configuration of axes 1, 4, 6),
``GET /logout`` (ends the session). Another mechanical unit is HTTP 400, another resource
404, a wrong password 401, more than :data:`MAX_SESSIONS` sessions 503, as on the controller.

Faults: every response goes through :meth:`simulator.faces.base.FaceServer.send` (dropped:
the request gets no response, the client's read times out; delayed; late), ``robot_frozen``
freezes the joints, ``link_down`` closes the port and every connection.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import math
import os
import secrets
import shutil
import ssl
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from scipy.spatial.transform import Rotation

from simulator.cell import EmulatedCell
from simulator.config import AbbRwsSection
from simulator.faces.base import FaceServer

REALM = "validusers@robapi.abb"
#: Sessions a controller keeps at once (RWS 1.0: 70); one more is refused with 503.
MAX_SESSIONS = 70
#: Largest request head accepted [bytes] (request line and headers).
MAX_HEAD_BYTES = 16384
#: Largest request body read [bytes] (this face serves GETs; bodies are discarded).
MAX_BODY_BYTES = 65536
#: RWS status code of a successful reply, as the controller sends it.
RWS_OK = 294912
UNUSED_EXTERNAL_AXIS = "9E+09"

HAL_JSON = "application/hal+json;v=2.0"
XHTML_2 = "application/xhtml+xml;v=2.0"


@dataclass
class Request:
    """One parsed HTTP request."""

    method: str
    target: str
    headers: dict[str, str]
    path: str = field(init=False)
    query: dict[str, list[str]] = field(init=False)

    def __post_init__(self) -> None:
        parts = urlsplit(self.target)
        self.path = parts.path.rstrip("/") or "/"
        self.query = parse_qs(parts.query)


@dataclass
class Response:
    """One HTTP response."""

    status: int
    body: bytes = b""
    content_type: str = "text/plain"
    headers: list[tuple[str, str]] = field(default_factory=list)


REASONS = {
    200: "OK",
    204: "No Content",
    400: "Bad Request",
    401: "Unauthorized",
    404: "Not Found",
    405: "Method Not Allowed",
    503: "Service Unavailable",
}


def md5_hex(text: str) -> str:
    return hashlib.md5(text.encode(), usedforsecurity=False).hexdigest()


def parse_auth_params(value: str) -> dict[str, str]:
    """``key=value, key="quoted, value"`` → dict (the parameters of a Digest header)."""
    out: dict[str, str] = {}
    i, n = 0, len(value)
    while i < n:
        while i < n and value[i] in " ,":
            i += 1
        eq = value.find("=", i)
        if eq < 0:
            break
        key = value[i:eq].strip().lower()
        i = eq + 1
        if i < n and value[i] == '"':
            end = i + 1
            chars = []
            while end < n and value[end] != '"':
                if value[end] == "\\" and end + 1 < n:
                    end += 1
                chars.append(value[end])
                end += 1
            out[key] = "".join(chars)
            i = end + 1
        else:
            end = value.find(",", i)
            end = n if end < 0 else end
            out[key] = value[i:end].strip()
            i = end
    return out


class AbbRwsServer(FaceServer):
    """The EMULATED RWS port (see the module docstring)."""

    label = "abb-rws"

    def __init__(self, cell: EmulatedCell, section: AbbRwsSection) -> None:
        super().__init__(cell, section)
        self.rws = section.rws
        self.username = section.username
        self.password = section.password
        self._nonces: dict[str, int] = {}  # nonce → highest nc seen
        self._opaque = secrets.token_hex(16)
        self._sessions: set[str] = set()
        self._ssl: ssl.SSLContext | None = None
        self._cert_dir: Path | None = None
        #: Requests answered, by status [count] (tests read it).
        self.statuses: dict[int, int] = {}

    @property
    def scheme(self) -> str:
        return "https" if self.rws == "2.0" else "http"

    async def start(self) -> None:
        if self.rws == "2.0" and self._ssl is None:
            self._ssl = self._tls_context()
        if self._server is None and self._ssl is not None:
            self._server = await asyncio.start_server(
                self._client, self.host, self.port, reuse_address=True, ssl=self._ssl
            )
            self.port = self._server.sockets[0].getsockname()[1]
            return
        await super().start()

    async def stop(self) -> None:
        await super().stop()
        if not self._down and self._cert_dir is not None:
            shutil.rmtree(self._cert_dir, ignore_errors=True)
            self._cert_dir = None

    def _tls_context(self) -> ssl.SSLContext:
        section = self.section
        assert isinstance(section, AbbRwsSection)
        cert, key = section.cert_file, section.key_file
        if cert is None or key is None:
            cert, key = self._self_signed()
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        context.load_cert_chain(cert, key)
        return context

    def _self_signed(self) -> tuple[str, str]:
        """A fresh self-signed certificate for ``host`` (``openssl req``), as an OmniCore
        ships one; its path is :attr:`cert_path` (clients pin it)."""
        openssl = shutil.which("openssl")
        if openssl is None:
            raise RuntimeError(
                "robot_abb_rws: rws = 2.0 needs cert_file and key_file, or the openssl "
                "command to generate a self-signed certificate"
            )
        self._cert_dir = Path(tempfile.mkdtemp(prefix="cablecal-rws-"))
        cert, key = self._cert_dir / "cert.pem", self._cert_dir / "key.pem"
        args = ["req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes"]
        args += ["-days", "2", "-subj", "/CN=cablecal EMULATED OmniCore"]
        args += [
            "-addext",
            f"subjectAltName=IP:{self.host}",
            "-keyout",
            str(key),
            "-out",
            str(cert),
        ]
        subprocess.run(
            [openssl, *args],
            check=True,
            capture_output=True,
            timeout=30,
        )
        os.chmod(key, 0o600)
        return str(cert), str(key)

    @property
    def cert_path(self) -> Path | None:
        """The generated self-signed certificate (RWS 2.0 without ``cert_file``)."""
        return None if self._cert_dir is None else self._cert_dir / "cert.pem"

    # ------------------------------------------------------------------ HTTP
    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while True:
            try:
                head = await reader.readuntil(b"\r\n\r\n")
            except asyncio.LimitOverrunError as exc:
                raise ValueError("request head too large") from exc
            if len(head) > MAX_HEAD_BYTES:
                raise ValueError("request head too large")
            lines = head.decode("latin-1").split("\r\n")
            method, target, _version = lines[0].split(" ", 2)
            headers: dict[str, str] = {}
            for line in lines[1:]:
                if ":" in line:
                    name, value = line.split(":", 1)
                    headers[name.strip().lower()] = value.strip()
            length = int(headers.get("content-length", "0") or 0)
            if not 0 <= length <= MAX_BODY_BYTES:
                raise ValueError(f"request body of {length} bytes")
            if length:
                await reader.readexactly(length)
            request = Request(method, target, headers)
            response = self.handle(request)
            self.statuses[response.status] = self.statuses.get(response.status, 0) + 1
            await self.send(writer, encode_response(response))
            if headers.get("connection", "").lower() == "close":
                return

    def handle(self, request: Request) -> Response:
        """The response to ``request`` (authentication, then the resource)."""
        session, fresh_login = self._authenticate(request)
        if session is None:
            return self._challenge()
        if session == "":
            return self._error(503, "Too many sessions")
        response = self._resource(request, session)
        if fresh_login:
            response.headers += [
                ("Set-Cookie", f"-http-session-={session}; path=/; httponly"),
                ("Set-Cookie", f"ABBCX={len(self._sessions)}; path=/; httponly"),
            ]
        return response

    def _authenticate(self, request: Request) -> tuple[str | None, bool]:
        """``(session id, new login)``; ``(None, False)`` not authenticated, ``("", …)``
        authenticated but no session left."""
        cookies = _cookies(request.headers.get("cookie", ""))
        session = cookies.get("-http-session-")
        if session in self._sessions:
            return session, False
        auth = request.headers.get("authorization", "")
        ok = self._digest_ok(request, auth) if self.rws == "1.0" else self._basic_ok(auth)
        if not ok:
            return None, False
        if len(self._sessions) >= MAX_SESSIONS:
            return "", False
        session = secrets.token_hex(16)
        self._sessions.add(session)
        return session, True

    def _basic_ok(self, auth: str) -> bool:
        if not auth.lower().startswith("basic "):
            return False
        try:
            user, _, password = base64.b64decode(auth[6:]).decode().partition(":")
        except (ValueError, UnicodeDecodeError):
            return False
        return secrets.compare_digest(
            f"{user}:{password}".encode(), f"{self.username}:{self.password}".encode()
        )

    def _digest_ok(self, request: Request, auth: str) -> bool:
        if not auth.lower().startswith("digest "):
            return False
        p = parse_auth_params(auth[7:])
        nonce, nc_text = p.get("nonce", ""), p.get("nc", "")
        if nonce not in self._nonces or p.get("qop") != "auth" or p.get("uri") != request.target:
            return False
        try:
            nc = int(nc_text, 16)
        except ValueError:
            return False
        if nc <= self._nonces[nonce] or p.get("username") != self.username:
            return False  # a replayed request
        ha1 = md5_hex(f"{self.username}:{REALM}:{self.password}")
        ha2 = md5_hex(f"{request.method}:{p['uri']}")
        expected = md5_hex(f"{ha1}:{nonce}:{nc_text}:{p.get('cnonce', '')}:auth:{ha2}")
        if not secrets.compare_digest(expected, p.get("response", "")):
            return False
        self._nonces[nonce] = nc
        return True

    def _challenge(self) -> Response:
        if self.rws == "2.0":
            header = f'Basic realm="{REALM}"'
        else:
            nonce = secrets.token_hex(16)
            if len(self._nonces) > 1024:
                self._nonces.clear()
            self._nonces[nonce] = 0
            header = (
                f'Digest realm="{REALM}", domain="{self.host}", qop="auth", '
                f'nonce="{nonce}", opaque="{self._opaque}", algorithm=MD5, stale=FALSE'
            )
        response = self._error(401, "Unauthorized")
        response.headers.append(("WWW-Authenticate", header))
        return response

    # ------------------------------------------------------------------ resources
    def _resource(self, request: Request, session: str) -> Response:
        path = request.path
        if path == "/logout":
            self._sessions.discard(session)
            return Response(204)
        prefix = "/rw/motionsystem/mechunits/"
        if not path.startswith(prefix):
            return self._error(404, f"no resource {path}")
        unit, _, resource = path[len(prefix) :].partition("/")
        if resource not in ("jointtarget", "robtarget"):
            return self._error(404, f"no resource {path}")
        if request.method != "GET":
            return self._error(405, f"{request.method} not allowed on {path}")
        if unit != "ROB_1":
            return self._error(400, f"mechanical unit {unit} does not exist")
        q = self.cell.reported_joints()
        if resource == "jointtarget":
            values = {f"rax_{j + 1}": f"{float(q[j]):.6f}" for j in range(6)}
            values |= {f"eax_{a}": UNUSED_EXTERNAL_AXIS for a in "abcdef"}
            kind = "ms-jointtarget"
        else:
            x, y, z, a, b, c = self.cell.tcp_pose(q)
            qx, qy, qz, qw = Rotation.from_euler("xyz", [a, b, c], degrees=True).as_quat()
            quat = (qw, qx, qy, qz)
            values = {k: f"{v:.6f}" for k, v in zip("xyz", (x, y, z), strict=True)}
            values |= {f"q{i + 1}": f"{float(v):.8f}" for i, v in enumerate(quat)}
            # Configuration: quarter revolutions of axes 1, 4 and 6 (cfx: 0, not modelled).
            values |= {f"cf{j}": str(math.floor(float(q[j - 1]) / 90.0)) for j in (1, 4, 6)}
            values |= {"cfx": "0"} | {f"eax{a}": UNUSED_EXTERNAL_AXIS for a in "abcdef"}
            kind = "ms-robtargets"
        return self._state(request, f"/rw/motionsystem/mechunits/ROB_1/{resource}/", kind, values)

    def _state(self, request: Request, base: str, kind: str, values: dict[str, str]) -> Response:
        """A one-item state reply in the format the request asks for."""
        item = {"_type": kind, "_title": "ROB_1", **values}
        href = f"{self.scheme}://{self.host}:{self.port}{base}"
        if self.rws == "1.0" and request.query.get("json") == ["1"]:
            body = {"_links": {"base": {"href": href}}, "_embedded": {"_state": [item]}}
            return Response(200, json.dumps(body).encode(), "application/json")
        if self.rws == "2.0" and "json" in request.headers.get("accept", ""):
            body2 = {
                "_links": {"base": {"href": href}, "self": {"href": ""}},
                "status": {"code": RWS_OK},
                "state": [item],
            }
            return Response(200, json.dumps(body2).encode(), HAL_JSON)
        spans = "".join(f'<span class="{k}">{v}</span>' for k, v in values.items())
        html = (
            '<?xml version="1.0" encoding="UTF-8"?>'
            '<html xmlns="http://www.w3.org/1999/xhtml"><head><title>motionsystem</title>'
            f'<base href="{href}"/></head><body><div class="state"><ul>'
            f'<li class="{kind}" title="ROB_1">{spans}</li></ul></div></body></html>'
        )
        xhtml = "application/xhtml+xml" if self.rws == "1.0" else XHTML_2
        return Response(200, html.encode(), xhtml)

    def _error(self, http_status: int, message: str) -> Response:
        status: dict[str, object] = {"code": -1073445859, "msg": message}
        body = {"_embedded": {"status": status}} if self.rws == "1.0" else {"status": status}
        ctype = "application/json" if self.rws == "1.0" else HAL_JSON
        return Response(http_status, json.dumps(body).encode(), ctype)


def _cookies(header: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for part in header.split(";"):
        name, sep, value = part.strip().partition("=")
        if sep:
            out[name] = value
    return out


def encode_response(response: Response) -> bytes:
    """HTTP/1.1 response bytes (keep-alive, Content-Length)."""
    lines = [f"HTTP/1.1 {response.status} {REASONS.get(response.status, 'Error')}"]
    if response.status != 204:
        lines.append(f"Content-Type: {response.content_type}")
        lines.append(f"Content-Length: {len(response.body)}")
    lines += [f"{name}: {value}" for name, value in response.headers]
    lines.append("Server: cablecal EMULATED RWS")
    head = ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")
    return head + (b"" if response.status == 204 else response.body)


__all__ = ["AbbRwsServer", "encode_response", "parse_auth_params"]
