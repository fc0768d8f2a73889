"""Protocol simulators: real servers (Modbus, serial lines on pseudo-terminals, I++ DME) around the bench."""
