"""bem: collocation boundary-element solver of steady conduction around a sensor."""
from .conductance import ConductanceMatrix, K_from_S, S_from_K, isolate
