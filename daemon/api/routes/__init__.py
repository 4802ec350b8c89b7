"""One router module per resource, all mounted under ``/api/v1`` (``/metrics`` at the root)."""
