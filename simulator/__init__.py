"""The emulated cell: a virtual robot with a drawstring sensor, an emulated HY9648 indicator
(Modbus RTU on a pseudo-terminal, optionally TCP) and emulated robot controllers (Huashu
SocketCmd, UR-style Modbus TCP), with fault injection and a control port.

Everything here is emulated; nothing talks to real hardware.
"""
