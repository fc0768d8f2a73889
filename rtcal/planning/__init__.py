"""Before anything moves: a plan's predicted uncertainty and duration, a better choice of CMM points,
and the Monte Carlo of whole simulated runs that checks the reported uncertainty."""
