"""Small spheres through the dipole term; contact impedance as series resistances."""
import numpy as np
import pytest

from electrosense.meshes.objects import Box, Sphere
from electrosense.meshes.sensor import preset
from electrosense.meshes.tank import Tank
from electrosense.psm import (
    PlacementError,
    PolySphericalModel,
    conductance,
    isolated_conductance,
    potential_coefficients,
)
from electrosense.psm.contact import electrode_areas_m2
from electrosense.psm.objects import contrast

SIGMA = 0.0354
MODEL4 = PolySphericalModel.collinear([0.0072, 0.0074, 0.0074, 0.0072], [0.0785, 0.0769, 0.0785])


def test_contrast_limits():
    assert contrast(float("inf"), SIGMA) == 1.0
    assert contrast(0.0, SIGMA) == -0.5
    assert contrast(SIGMA, SIGMA) == 0.0


def test_free_space_object_term_is_the_closed_form_and_superposes():
    objs = (Sphere((0.05, 0.06, 0.0), float("inf"), radius_m=0.015), Sphere((-0.1, -0.05, 0.02), 0.0, radius_m=0.01))
    X = MODEL4.centres_m
    R = potential_coefficients(MODEL4.radii_m, X)
    for o in objs:
        chi, b, xo = contrast(o.conductivity_S_per_m, SIGMA), o.radius_m, np.array(o.centre_m)
        u = X - xo
        r3 = np.linalg.norm(u, axis=1) ** 3
        R = R + chi * b**3 * (u @ -u.T) / np.outer(r3, r3)
    expected = isolated_conductance(R / (4 * np.pi * SIGMA), 4)
    got = conductance(MODEL4, np.zeros((1, 4)), SIGMA, objects=objs).K_S[0]
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_conducting_sphere_draws_current_and_insulating_sphere_blocks_it():
    near = (0.0, 0.05, 0.0)
    I0 = conductance(MODEL4, np.zeros((1, 4)), SIGMA).receiver_currents_A()
    Ic = conductance(MODEL4, np.zeros((1, 4)), SIGMA, objects=[Sphere(near, "conducting", radius_m=0.02)]).receiver_currents_A()
    Ii = conductance(MODEL4, np.zeros((1, 4)), SIGMA, objects=[Sphere(near, "insulating", radius_m=0.02)]).receiver_currents_A()
    # the sphere sits between the two rings, in the field of the emitter: it changes the middle receivers most
    assert np.sign(Ic - I0)[0, 1] == -np.sign(Ii - I0)[0, 1]
    assert np.all(np.abs(Ic - I0) > np.abs(Ii - I0))  # |chi| = 1 against 1/2, same geometry, first order
    far = conductance(MODEL4, np.zeros((1, 4)), SIGMA, objects=[Sphere((50.0, 0, 0), "conducting", radius_m=0.02)])
    np.testing.assert_allclose(far.receiver_currents_A(), I0, rtol=1e-9)


def test_objects_in_the_tank_see_the_images():
    tank = Tank((1.0, 1.0, 1.0))
    obj = [Sphere((0.2, 0.1, 0.0), "conducting", radius_m=0.03)]
    pose = np.array([[0.2, 0.0, 0.0, 0.0]])
    with_tank = conductance(MODEL4, pose, SIGMA, tank, objects=obj).K_S - conductance(MODEL4, pose, SIGMA, tank).K_S
    free = conductance(MODEL4, pose, SIGMA, objects=obj).K_S - conductance(MODEL4, pose, SIGMA).K_S
    assert np.abs(with_tank - free).max() > 1e-3 * np.abs(free).max()


def test_bad_objects_are_refused():
    with pytest.raises(ValueError, match="spheres only"):
        conductance(MODEL4, np.zeros((1, 4)), SIGMA, objects=[Box((0.0, 0.1, 0.0))])
    with pytest.raises(PlacementError, match="overlaps sphere 1"):
        conductance(MODEL4, np.zeros((1, 4)), SIGMA, objects=[Sphere((0.12, 0.0, 0.0), radius_m=0.01)])
    with pytest.raises(PlacementError, match="object 1"):
        conductance(MODEL4, np.zeros((1, 4)), SIGMA, Tank((1.0, 1.0, 1.0)), objects=[Sphere((0.49, 0.3, 0.0), radius_m=0.02)])


def test_electrode_areas_hemisphere_collar_partial_cap_and_ring():
    from electrosense.meshes.sensor import Electrode, SensorDescription

    r = 0.01
    s = SensorDescription("t", r, 0.2, (Electrode("cap", 0.085, 0.1), Electrode("ring", 0.0, 0.02),
                                        Electrode("cap", -0.1, -0.095)))
    A = electrode_areas_m2(s)
    np.testing.assert_allclose(A, [2 * np.pi * r**2 + 2 * np.pi * r * 0.005,  # hemisphere + 5 mm collar
                                   2 * np.pi * r * 0.02,  # ring
                                   2 * np.pi * r * 0.005])  # spherical cap of height 5 mm (Archimedes)
    assert electrode_areas_m2(preset("angels-4")).shape == (4,)


def test_contact_impedance_is_a_series_resistance():
    m = PolySphericalModel.collinear([0.007, 0.007], [0.2], electrode_areas_m2=[3e-4, 5e-4])
    z = 0.02
    R0 = conductance(m, np.zeros((1, 4)), SIGMA).resistance_ohm[0, 0]
    Rc = conductance(m, np.zeros((1, 4)), SIGMA, contact_impedance_ohm_m2=z).resistance_ohm[0, 0]
    assert Rc == pytest.approx(R0 + z / 3e-4 + z / 5e-4, rel=1e-12)
    Rk = conductance(m, np.zeros((1, 4)), SIGMA, contact_impedance_ohm_m2=[z, 0.0]).resistance_ohm[0, 0]
    assert Rk == pytest.approx(R0 + z / 3e-4, rel=1e-12)


def test_contact_impedance_needs_electrode_areas():
    m = PolySphericalModel.collinear([0.007, 0.007], [0.2])
    with pytest.raises(ValueError, match="areas of the real electrodes"):
        conductance(m, np.zeros((1, 4)), SIGMA, contact_impedance_ohm_m2=0.01)
    C = conductance(m, np.zeros((1, 4)), SIGMA, contact_impedance_ohm_m2=0.01, sensor=preset("angels-2"))
    assert C.resistance_ohm[0, 0] > conductance(m, np.zeros((1, 4)), SIGMA).resistance_ohm[0, 0]
