"""Parameter tuning (issue 19): a declared parameter table, hill climbing and a genetic
algorithm (seed thesis section 5.6), fitness from replays of drives, profiles.

``navsvc.tuning.run`` (the run loop) and ``navsvc.tuning.replay`` import the session; they
are imported by name, so that ``navsvc.session`` may use this package's pure parts.
"""

from navsvc.tuning.fitness import DriveScore, route_score, truth_score
from navsvc.tuning.params import BY_NAME, DEFAULT_SET, TABLE, Parameter, decode, select
from navsvc.tuning.search import METHODS, Genetic, HillClimb, start_search

__all__ = ["BY_NAME", "DEFAULT_SET", "METHODS", "TABLE", "DriveScore", "Genetic", "HillClimb",
           "Parameter", "decode", "route_score", "select", "start_search", "truth_score"]
