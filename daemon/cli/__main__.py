"""``python -m daemon.cli``: the ``cablecal`` command line."""

from daemon.cli import main

main()
