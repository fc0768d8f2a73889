"""The laser-tracer multi-station method (seed 000): everything that is this method's."""
