"""psm: the poly-spherical model of Jawad et al. (images for the tank, objects, calibration)."""
