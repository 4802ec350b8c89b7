"""Robot data: the library of built-in arms (library/*.toml) and UR factory calibrations."""
