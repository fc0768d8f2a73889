"""Before anything moves: a plan's predicted uncertainty and duration, the levers of its method's planner
and the shortest plan for a target U, and the Monte Carlo of whole simulated runs that checks the
reported uncertainty."""
