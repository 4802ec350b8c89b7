"""``python -m simulator [--config sim.toml]``: same as ``cablecal simulate``
(:mod:`simulator.entry`)."""

from __future__ import annotations

from simulator.entry import main

if __name__ == "__main__":
    main()
