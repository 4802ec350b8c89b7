"""ABB Robot Web Services: the joints of a mechanical unit from its jointtarget
(``GET /rw/motionsystem/mechunits/{mechunit}/jointtarget``, ``rax_1`` … ``rax_6`` [deg]).

- ``rws = "1.0"`` (IRC5, RobotWare 6): HTTP, digest authentication, ``?json=1`` for JSON
  (``application/json``, the state under ``_embedded._state``).
- ``rws = "2.0"`` (OmniCore, RobotWare 7): HTTPS, basic authentication, ``Accept:
  application/hal+json;v=2.0`` (the state under ``state``). An OmniCore ships a self-signed
  certificate: pin it with ``ca_file`` (its PEM, exported from the controller), or set
  ``verify_tls = false`` on a closed cell network.

Both keep the controller's session cookie (across reconnects too), so a login costs one
challenge per session, and ``close()`` logs out (``GET /logout``): a controller keeps few
sessions (70 on an IRC5).

Why not abb_robot_client (pip ``abb-robot-client``, maintained by Wason Technology): its
``RWS`` class is blocking (requests) and passes no timeout to any request, so a controller
that stops answering blocks the caller forever; its asyncio ``RWS`` (``rws_aio``, httpx) has
no timeout setting (httpx's fixed 5 s default) and both speak RWS 1.0 only (digest auth,
``_embedded._state``), not an OmniCore's RWS 2.0. Reading one resource needs a GET and a
JSON lookup, which httpx (already a dependency) does with per-request timeouts and both
authentication schemes; the cross-check test reads the emulated controller with
abb_robot_client's ``RWS`` to hold both to the same wire.

The password comes from ``password_file`` (mode 0600) or the environment variable named by
``password_env`` (:mod:`drivers.credentials`); it is never logged or shown.

Retries: every attempt is a new HTTP request; a timed-out request's connection is discarded
by httpx, so a late response can never be read as the next request's. HTTP 401 is a
:class:`~drivers.errors.RobotProtocolError` naming the user (not the password).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import ssl
from pathlib import Path
from typing import Annotated, Literal

import httpx
from pydantic import Field, PrivateAttr, SecretStr

from drivers.credentials import read_secret
from drivers.robot_link import LinkConfig, LinkedRobot, LinkLost

#: ABB's factory-default login of a new controller (public). The emulated face
#: (``simulator.config.AbbRwsSection``) states it again on purpose: the simulator is written
#: independently of the drivers, so a wrong default here fails against it.
ABB_FACTORY_USER = "Default User"
ABB_FACTORY_PASSWORD = "robotics"
HAL_JSON = "application/hal+json;v=2.0"
#: Largest response body read [bytes] (a jointtarget is < 1 kB).
MAX_BODY_BYTES = 65536


class AbbRwsConfig(LinkConfig):
    """Configuration of :class:`AbbRwsRobot`; the link settings (timeouts, retries,
    back-off, ``max_unchanged_s``) are :class:`drivers.robot_link.LinkConfig`'s.

    ``port``: 80 for RWS 1.0 (IRC5); set 443 for RWS 2.0 (OmniCore). ``mechunit``: the
    mechanical unit (``ROB_1`` for the first robot). ``password_env`` / ``password_file``: where the
    password is (the file wins when both are set).
    """

    kind: Literal["abb-rws"] = "abb-rws"
    port: Annotated[int, Field(ge=1, le=65535)] = 80
    rws: Literal["1.0", "2.0"] = "1.0"
    mechunit: Annotated[str, Field(pattern=r"^[A-Za-z0-9_]{1,32}$")] = "ROB_1"
    username: str = ABB_FACTORY_USER
    password_env: str | None = "CABLECAL_ROBOT_PASSWORD"
    password_file: Path | None = None
    verify_tls: bool = True
    ca_file: Path | None = None
    _password: SecretStr | None = PrivateAttr(default=None)

    def password(self) -> SecretStr:
        """The password (read once). Raises :class:`drivers.credentials.CredentialsError`."""
        if self._password is None:
            self._password = read_secret(self.password_env, self.password_file, "password")
        return self._password

    def check(self) -> None:
        """Validate what cannot be checked field by field (the password source)."""
        self.password()


class AbbRwsRobot(LinkedRobot):
    """Asyncio RWS reader of a mechanical unit's jointtarget (see the module docstring)."""

    #: The robot maker whose controller this driver reads (the robot library's words).
    MAKER = "abb"

    def __init__(self, config: AbbRwsConfig) -> None:
        super().__init__(config)
        self.config = config
        self.joints_what = f"{config.mechunit} jointtarget"
        self._password = config.password()  # fails now, naming the source, not at 1st read
        self._client: httpx.AsyncClient | None = None
        self._cookies = httpx.Cookies()
        scheme = "https" if config.rws == "2.0" else "http"
        self.base_url = f"{scheme}://{config.host}:{config.port}"
        path = f"/rw/motionsystem/mechunits/{config.mechunit}/jointtarget"
        self._url = self.base_url + path + ("?json=1" if config.rws == "1.0" else "")

    def _is_open(self) -> bool:
        return self._client is not None

    async def _open(self) -> None:
        cfg = self.config
        user, password = cfg.username, self._password.get_secret_value()
        auth: httpx.Auth = (
            httpx.DigestAuth(user, password)
            if cfg.rws == "1.0"
            else httpx.BasicAuth(user, password)
        )
        verify: bool | ssl.SSLContext = cfg.verify_tls
        if cfg.ca_file is not None:  # the controller's own (self-signed) certificate, pinned
            verify = ssl.create_default_context(cafile=str(cfg.ca_file))
        headers = {"Accept": HAL_JSON} if cfg.rws == "2.0" else {}
        self._client = httpx.AsyncClient(
            auth=auth,
            cookies=self._cookies,
            verify=verify,
            headers=headers,
            timeout=cfg.timeout_s,
            follow_redirects=False,
            limits=httpx.Limits(max_connections=1, max_keepalive_connections=1),
        )
        # The login (digest challenge, or basic) happens in the first read, under the retry
        # policy; a refused login is then a RobotProtocolError naming the user.

    async def _close(self) -> None:
        """Close the HTTP client, keeping the session cookie: after a lost link the next
        client continues the controller session (no new login, no orphaned session)."""
        client, self._client = self._client, None
        if client is not None:
            self._cookies = httpx.Cookies(client.cookies)
            with contextlib.suppress(Exception):
                await client.aclose()

    async def close(self) -> None:
        """Log out (``GET /logout``, frees the controller's session) and close."""
        client = self._client
        if client is not None:
            with contextlib.suppress(Exception):
                async with asyncio.timeout(0.5):
                    await client.get(self.base_url + "/logout")
        await self._close()
        self._cookies = httpx.Cookies()

    async def _request_joints(self, timeout_s: float) -> list[float]:
        """One GET of the jointtarget; ``rax_1`` … ``rax_6`` [deg]."""
        client = self._client
        if client is None:
            raise LinkLost("not connected")
        self.frames.note(f"tx GET {self._url}")
        try:
            async with asyncio.timeout(timeout_s):
                response = await client.get(self._url)
        except TimeoutError:
            raise
        except httpx.TimeoutException as exc:
            raise TimeoutError from exc
        except (httpx.TransportError, OSError) as exc:
            raise LinkLost(f"{type(exc).__name__}: {exc}") from exc
        body = response.content[:MAX_BODY_BYTES]
        text = body[:200].decode("utf-8", errors="replace")
        self.frames.note(f"rx HTTP {response.status_code} {text}")
        if response.status_code == 401:
            raise self.protocol_error(
                f"HTTP 401: the controller refused user {self.config.username!r} "
                "(check the password source and the user's RWS grants)",
                401,
            )
        if response.status_code != 200:
            raise self.protocol_error(
                f"{self.joints_what}: HTTP {response.status_code}: {_rws_message(body)}",
                response.status_code,
            )
        return self._parse(response)

    def _parse(self, response: httpx.Response) -> list[float]:
        try:
            data = response.json()
            states = data["_embedded"]["_state"] if self.config.rws == "1.0" else data["state"]
            state = states[0]
        except (ValueError, KeyError, IndexError, TypeError) as exc:
            raise self.protocol_error(f"{self.joints_what}: not an RWS state reply") from exc
        if not isinstance(state, dict) or state.get("_type") != "ms-jointtarget":
            raise self.protocol_error(f"{self.joints_what}: reply is not an ms-jointtarget")
        try:
            values = [float(state[f"rax_{j}"]) for j in range(1, 7)]
        except (KeyError, TypeError, ValueError) as exc:
            raise self.protocol_error(f"{self.joints_what}: rax_1..rax_6: {exc}") from exc
        if not all(math.isfinite(v) for v in values):
            raise self.protocol_error(f"{self.joints_what}: non-finite axis value {values}")
        return values


def _rws_message(body: bytes) -> str:
    """The controller's error message of an error reply (``status.msg``), else the start
    of the body."""
    with contextlib.suppress(ValueError, TypeError, AttributeError):
        data = json.loads(body)
        status = data.get("status") or data.get("_embedded", {}).get("status", {})
        if isinstance(status, dict) and status.get("msg"):
            return str(status["msg"])[:200]
    return body[:120].decode("utf-8", errors="replace")


__all__ = ["ABB_FACTORY_PASSWORD", "ABB_FACTORY_USER", "AbbRwsConfig", "AbbRwsRobot"]
