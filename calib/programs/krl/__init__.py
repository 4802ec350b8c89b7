"""KUKA KRL: everything cablecal reads or writes in this language.

Modules: `program` (write and read back a `.src` of PTP axis moves), `filter` (correct
`.src`/`.dat` pairs; `$config.dat` read, never written) with `data` (comments, aggregates,
`.dat` declarations) and `moves` (a `.src`'s moves with the tool and base in force).
"""
