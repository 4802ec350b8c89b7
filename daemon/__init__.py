"""The cablecal service: the daemon, its REST API, the operator page and the command line."""

#: The release, its one home: ``pyproject.toml`` reads it (``[tool.setuptools.dynamic]``),
#: ``GET /health`` reports it.
__version__ = "0.1.0"
