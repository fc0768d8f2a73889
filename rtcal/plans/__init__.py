"""Plans: each method's order of work as steps for the engine (:mod:`rtcal.engine`).

A plan knows which device moves where, what is read, and how each reading is checked against the
command (the method's knowledge); it does no I/O. The engine executes it; the walker times it.
"""
