"""Fanuc TP (ASCII `.LS`): everything cablecal reads or writes in this language.

Modules: `program` (write and read back an `.LS` of joint positions), `filter` (correct a
plant's `.LS` positions) and `config` (the CONFIG string `'F U T, t1, t4, t6'`, one rule each).
"""
