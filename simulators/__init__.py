"""The simulated bench (one geometric error model), simulated instruments, protocol servers."""
