"""The robot's pose from its currents: per-sample maximum likelihood with a fast model (a tank map, or the PSM),
tracked along a log, and the Cramer-Rao bound it is measured against (:mod:`.track`, :mod:`.from_log`)."""
