"""Defaults the command line shows in its help, here so that ``--help`` needs no pydantic
(daemon/config.py, the one place the settings are validated, reads them from here)."""

#: The REST API's TCP port (unprivileged, so the unit needs no capability).
API_PORT = 8080
