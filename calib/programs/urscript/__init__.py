"""Universal Robots URScript: everything cablecal reads or writes in this language.

Modules: `program` (write and read back a script of `movej` joint moves), `filter` (correct a
plant's scripts and PolyScope exports).
"""
