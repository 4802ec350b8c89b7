"""``python -m daemon``: the ``cablecal`` command line."""

from daemon.cli import main

main()
