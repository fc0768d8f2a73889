"""The encoder Abbe-error method (seed 001) and the ISO 230-2 test: everything that is this method's."""
