"""ABB RAPID: everything cablecal reads or writes in this language.

Modules: `program` (write and read back a joint-target module), `filter` (correct a plant's
modules' targets) with `syntax` (comments, strings, bracketed literals), `decls` (modules,
routines, declarations and their scope) and `moves` (move arguments and ConfL/ConfJ in force).
"""
