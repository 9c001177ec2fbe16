"""Calibration of the PSM on a reference conductance matrix (section II.B of the paper).

The spheres are put on the sensor axis (head first, centred on the origin)
and their radii and centre distances are fitted by least squares on the
paper's criterion (17)::

    Gamma = sqrt( Tr((S_ref - S_PSM)^2) / Tr(S_ref^2) ),

where S is the (n-1) x (n-1) conductance matrix without the emitter
(positive diagonal), the reference typically the free-space BEM of the real
sensor. The residual vector holds the m(m+1)/2 distinct entries of
``(S_ref - S_PSM) / ||S_ref||_F`` (off-diagonal ones weighted by sqrt 2), so
its norm is Gamma.

Layouts: all radii and gaps free (``symmetric=False``), or the paper's
symmetry (``symmetric=True``: mirror-equal radii and gaps, e.g. a_e, a_i,
L_e, L_i for n = 4); ``fix_length_m`` fixes the distance between the outer
spheres (the paper's n = 2 case: L = 20 cm, one radius). A layout with more
parameters than the reference has distinct entries is refused.

Uncertainties come from the Jacobian J of the residual at the optimum:
``cov = s^2 (J^T J)^-1`` with s^2 the residual variance per degree of
freedom when there are more data than parameters, otherwise the stated
uncertainty of the reference (``reference_uncertainty_S``, or its
``rounding_uncertainty_S`` info, or its asymmetry as a proxy of its
discretisation error, or else an assumed 1e-3 relative uncertainty,
stated in the result).

Example
-------
>>> from electrosense.psm.paper import paper_reference
>>> cal = calibrate(paper_reference(), symmetric=True)
>>> np.round(cal.parameters * 100, 2).tolist()  # a_e, a_i, L_e, L_i in cm (paper: 0.72, 0.74, 7.85, 7.69)
[0.72, 0.74, 7.87, 7.73]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from electrosense.bem.conductance import ConductanceMatrix, S_from_K
from electrosense.psm.conductance import conductance_array
from electrosense.psm.contact import electrode_areas_m2
from electrosense.psm.model import ModelError, PolySphericalModel
from electrosense.psm.potential_coefficients import isolated_conductance, potential_coefficients

__all__ = ["Calibration", "CalibrationError", "calibrate", "gamma_criterion", "Layout"]


#: relative uncertainty assumed for a reference that states none, when the fit is exact (the BEM's
#: discretisation error on the default meshes is of this order, see the BEM notes)
ASSUMED_REFERENCE_REL_UNCERTAINTY = 1e-3


class CalibrationError(ValueError):
    """A reference that cannot be fitted (not symmetric, not definite, too few data)."""


def gamma_criterion(S_ref: np.ndarray, S_model: np.ndarray) -> float:
    """The paper's criterion (17): ``sqrt(Tr((S_ref - S)^2) / Tr(S_ref^2))``."""
    D = np.asarray(S_ref) - np.asarray(S_model)
    return float(np.sqrt(np.trace(D @ D) / np.trace(np.asarray(S_ref) @ np.asarray(S_ref))))


@dataclass(frozen=True)
class Layout:
    """Which radii and gaps share a parameter, and which gap group the fixed length determines."""

    n: int
    symmetric: bool
    fix_length_m: float | None

    @property
    def radius_groups(self) -> list[list[int]]:
        n = self.n
        if not self.symmetric:
            return [[k] for k in range(n)]
        return [sorted({k, n - 1 - k}) for k in range((n + 1) // 2)]

    @property
    def gap_groups(self) -> list[list[int]]:
        g = self.n - 1
        if not self.symmetric:
            return [[k] for k in range(g)]
        return [sorted({k, g - 1 - k}) for k in range((g + 1) // 2)]

    @property
    def free_gap_groups(self) -> list[list[int]]:
        groups = self.gap_groups
        return groups if self.fix_length_m is None else groups[:-1]

    @property
    def names(self) -> list[str]:
        def label(prefix, groups, fmt):
            return [prefix + "=".join(fmt(k) for k in grp) for grp in groups]
        radii = ["=".join(f"a_{k + 1}" for k in grp) for grp in self.radius_groups]
        gaps = ["=".join(f"L_{k + 1}{k + 2}" for k in grp) for grp in self.free_gap_groups]
        return radii + gaps

    @property
    def n_free(self) -> int:
        return len(self.radius_groups) + len(self.free_gap_groups)

    def expand(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radii (n,) and gaps (n-1,) from the free parameters."""
        nr = len(self.radius_groups)
        radii = np.empty(self.n)
        for value, grp in zip(theta[:nr], self.radius_groups):
            radii[grp] = value
        gaps = np.empty(self.n - 1)
        for value, grp in zip(theta[nr:], self.free_gap_groups):
            gaps[grp] = value
        if self.fix_length_m is not None:
            last = self.gap_groups[-1]
            rest = sum(theta[nr + i] * len(grp) for i, grp in enumerate(self.free_gap_groups))
            gaps[last] = (self.fix_length_m - rest) / len(last)
        return radii, gaps


@dataclass(frozen=True)
class Calibration:
    """Result of :func:`calibrate`: the model, the criterion and the fitted parameters (m)."""

    model: PolySphericalModel
    gamma_criterion: float
    parameter_names: tuple[str, ...]
    parameters: np.ndarray
    uncertainties: np.ndarray
    correlations: np.ndarray
    uncertainty_basis: str
    n_data: int
    reference: ConductanceMatrix

    def summary(self) -> str:
        """A short text table: parameters in cm with uncertainties, Gamma, correlations."""
        lines = [f"PSM calibration on {self.n_data} distinct conductances: Gamma = {self.gamma_criterion:.3e}"]
        for name, v, u in zip(self.parameter_names, self.parameters, self.uncertainties):
            lines.append(f"  {name:<14s} {v * 100:9.4f} cm  +- {u * 100:.2e} cm")
        lines.append(f"  uncertainties from: {self.uncertainty_basis}")
        if len(self.parameters) > 1:
            lines.append("  correlations: " + np.array2string(self.correlations, precision=3, suppress_small=True))
        return "\n".join(lines)


def _check_reference(reference: ConductanceMatrix, symmetry_tolerance: float) -> np.ndarray:
    if not isinstance(reference, ConductanceMatrix):
        raise CalibrationError(f"the reference must be a bem.conductance.ConductanceMatrix, got {type(reference).__name__}")
    if reference.batch_shape not in ((), (1,)):
        raise CalibrationError(f"the reference must be one conductance matrix, got a batch of shape {reference.batch_shape}")
    K = reference.K_S.reshape(reference.n, reference.n)
    asym = float(np.max(np.abs(K - K.T)) / np.max(np.abs(K)))
    if asym > symmetry_tolerance:
        raise CalibrationError(
            f"the reference K is not symmetric: max|K - K^T| / max|K| = {asym:.3g} > {symmetry_tolerance:g} "
            "(a reciprocal medium has a symmetric K; refine the BEM mesh or check the matrix)"
        )
    S = S_from_K(0.5 * (K + K.T), reference.emitter)
    eig = np.linalg.eigvalsh(S)
    if eig.min() <= 0:
        raise CalibrationError(
            f"the reference S (K without the emitter) is not positive definite: eigenvalues {eig.tolist()} "
            "(S must have a positive diagonal: current INTO the receivers per volt of V_emitter - V_receiver)"
        )
    return S


def _tank_terms(tank_reference, reference: ConductanceMatrix, symmetry_tolerance: float):
    """Tank, poses (Q, 4), symmetrised S (Q, m, m) and their Frobenius norms from a tank reference."""
    try:
        tank, poses, C = tank_reference
    except (TypeError, ValueError):
        raise CalibrationError("tank_reference must be (tank, poses (Q, 4), ConductanceMatrix of batch (Q,))") from None
    poses = np.asarray(poses, dtype=float).reshape(-1, 4)
    if not isinstance(C, ConductanceMatrix) or C.batch_shape != (poses.shape[0],):
        raise CalibrationError(f"tank_reference: need one conductance matrix per pose ({poses.shape[0]})")
    if C.n != reference.n or C.emitter != reference.emitter:
        raise CalibrationError("tank_reference: electrode count or emitter differs from the free-space reference")
    if C.asymmetry > symmetry_tolerance:
        raise CalibrationError(f"tank_reference: K is not symmetric (asymmetry {C.asymmetry:.3g} > {symmetry_tolerance:g})")
    K = C.scaled_to(reference.sigma_S_per_m).K_S
    S = S_from_K(0.5 * (K + np.swapaxes(K, -1, -2)), C.emitter)
    return tank, poses, S, np.sqrt(np.einsum("qij,qji->q", S, S))


def _model_S(layout: Layout, theta: np.ndarray, sigma: float, emitter: int) -> np.ndarray:
    radii, gaps = layout.expand(theta)
    x = np.concatenate([[0.0], -np.cumsum(gaps)])
    c = np.zeros((layout.n, 3))
    c[:, 0] = x
    R = potential_coefficients(radii, c)
    return S_from_K(isolated_conductance(R / (4 * np.pi * sigma), emitter), emitter)


def calibrate(reference: ConductanceMatrix, symmetric: bool = False, fix_length_m: float | None = None, *,
              sensor=None, reference_uncertainty_S: float | None = None, symmetry_tolerance: float = 0.02,
              initial_m: np.ndarray | None = None, tank_reference=None) -> Calibration:
    """Fit the PSM's radii and centre distances to ``reference`` on the criterion (17).

    Parameters
    ----------
    reference : ConductanceMatrix
        One free-space conductance matrix (BEM, or the paper's table).
    symmetric : bool
        The paper's symmetry: mirror-equal radii and gaps.
    fix_length_m : float, optional
        Fix the distance between the outermost sphere centres.
    sensor : SensorDescription, optional
        The real sensor: its electrode areas are stored for the contact impedance.
    reference_uncertainty_S : float, optional
        Standard uncertainty of each entry of S (siemens), used when the fit
        has no degree of freedom left.
    symmetry_tolerance : float
        Largest accepted ``max|K - K^T| / max|K|`` of the reference.
    initial_m : array, optional
        Starting parameters (m), in the order of the layout's names.
    tank_reference : (Tank, poses (Q, 4), ConductanceMatrix of batch (Q,)), optional
        An extension beyond the paper: reference conductances of the real
        sensor at a few poses in a tank (BEM). Their criterion (17), pose by
        pose with the complete images, joins the free-space one in the least
        squares; this fixes where the spheres sit along the axis (which the
        free-space S of a 2-electrode sensor cannot) from the walls' effect.
        ``gamma_criterion`` stays the free-space criterion; the tank one is in
        ``model.info["fit"]["gamma_tank"]``.

    Raises
    ------
    CalibrationError
        Non-symmetric or non-definite reference; more parameters than data;
        a fit whose spheres overlap.
    """
    S_ref = _check_reference(reference, symmetry_tolerance)
    if reference.info.get("unbounded") is False or reference.info.get("tank_size_m") is not None:
        raise CalibrationError(
            f"the reference was computed in a tank ({reference.info.get('tank_size_m')} m): calibrate on the sensor "
            "in unbounded water (esense conductance --unbounded); tank poses go in tank_reference"
        )
    n, emitter, sigma = reference.n, reference.emitter, float(reference.sigma_S_per_m)
    if fix_length_m is not None and not fix_length_m > 0:
        raise CalibrationError(f"fix_length_m must be positive, got {fix_length_m}")
    layout = Layout(n, bool(symmetric), None if fix_length_m is None else float(fix_length_m))
    m = n - 1
    n_data = m * (m + 1) // 2
    tank_terms = None
    if tank_reference is not None:
        tank_terms = _tank_terms(tank_reference, reference, symmetry_tolerance)
        n_data += tank_terms[2].shape[0] * (m * (m + 1) // 2)
    if layout.n_free > n_data:
        raise CalibrationError(
            f"the reference has {n_data} distinct conductance(s) but the {'symmetric' if symmetric else 'free'} "
            f"layout of {n} spheres has {layout.n_free} parameters ({', '.join(layout.names)}); "
            "use symmetric=True and/or fix_length_m (esense calibrate --symmetric / --fix-length)"
        )
    iu = np.triu_indices(m)
    weight = np.where(iu[0] == iu[1], 1.0, np.sqrt(2.0))
    norm = np.sqrt(np.trace(S_ref @ S_ref))

    def free_residual(theta):
        return weight * (_model_S(layout, theta, sigma, emitter) - S_ref)[iu] / norm

    def tank_residual(theta):
        tank, poses, S_tank, norms = tank_terms
        radii, gaps = layout.expand(theta)
        try:
            model = PolySphericalModel.collinear(radii, gaps, emitter)
            K, _ = conductance_array(model, poses, sigma, tank, "complete", image_shells=4)
        except ValueError:  # overlapping spheres or spheres out of the water on the way: a large residual
            return np.ones(S_tank.shape[0] * len(iu[0]))
        S = S_from_K(K, emitter)
        return (weight * (S - S_tank)[:, iu[0], iu[1]] / norms[:, None]).ravel()

    def residual(theta):
        if tank_terms is None:
            return free_residual(theta)
        return np.concatenate([free_residual(theta), tank_residual(theta)])

    nr = len(layout.radius_groups)
    a0 = float(np.mean(np.diag(S_ref))) / (4 * np.pi * sigma)
    starts = []
    if initial_m is not None:
        starts.append(np.asarray(initial_m, dtype=float))
    lengths = [fix_length_m] if fix_length_m is not None else [0.1, 0.2, 0.4]
    for length in lengths:
        for fa in (0.8, 1.3):
            gap = length / (n - 1)
            starts.append(np.array([fa * a0] * nr + [gap] * len(layout.free_gap_groups)))
    lower = np.full(layout.n_free, 1e-6)
    best = None
    for x0 in starts:
        x0 = np.maximum(x0, 2e-6)
        try:
            res = least_squares(residual, x0, bounds=(lower, np.inf), x_scale=np.abs(x0),
                                ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=2000)
        except ValueError:
            continue
        if best is None or res.cost < best.cost:
            best = res
    if best is None:
        raise CalibrationError("the least-squares fit failed from every starting point")
    theta = best.x
    radii, gaps = layout.expand(theta)
    try:
        model_areas = None if sensor is None else electrode_areas_m2(sensor)
        model = PolySphericalModel.collinear(radii, gaps, emitter, electrode_areas_m2=model_areas)
    except ModelError as exc:
        raise CalibrationError(f"the best fit is not a valid model: {exc}") from None
    r = residual(theta)
    gamma = float(np.linalg.norm(free_residual(theta)))
    J = best.jac
    dof = n_data - layout.n_free
    if dof > 0:
        s2, basis = float(r @ r) / dof, f"residual variance ({dof} degree(s) of freedom)"
    else:
        u = reference_uncertainty_S if reference_uncertainty_S is not None else reference.info.get("rounding_uncertainty_S")
        if u is not None:
            s2, basis = (float(u) / norm) ** 2, f"stated uncertainty of the reference entries ({float(u):.3g} S)"
        elif reference.asymmetry > 1e-6:
            s2 = (reference.asymmetry * float(np.max(np.abs(S_ref))) / norm) ** 2
            basis = "the reference's asymmetry, as a proxy of its discretisation error (exact fit, no residual)"
        else:
            s2 = (ASSUMED_REFERENCE_REL_UNCERTAINTY * float(np.max(np.abs(S_ref))) / norm) ** 2
            basis = (f"an assumed relative uncertainty {ASSUMED_REFERENCE_REL_UNCERTAINTY:g} of the reference entries "
                     "(exact fit, no residual, no stated uncertainty: pass reference_uncertainty_S)")
    cov = s2 * np.linalg.pinv(J.T @ J)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    corr = np.where(np.outer(std, std) > 0, corr, np.eye(len(std)))
    names = tuple(layout.names)
    info = {
        "fit": {
            "symmetric": bool(symmetric), "fix_length_m": fix_length_m,
            "parameters_m": dict(zip(names, theta.tolist())),
            "uncertainties_m": dict(zip(names, std.tolist())),
            "correlations": corr.tolist(), "uncertainty_basis": basis,
        }
    }
    if tank_terms is not None:
        info["fit"]["gamma_tank"] = float(np.sqrt(np.mean(tank_residual(theta).reshape(tank_terms[2].shape[0], -1) ** 2, axis=0).sum()))
        info["fit"]["tank_poses"] = tank_terms[1].tolist()
        info["fit"]["tank_size_m"] = list(tank_terms[0].size_m)
    if sensor is not None:
        info["sensor"] = sensor.name
    model = PolySphericalModel(model.radii_m, model.centres_m, emitter, gamma, reference.to_json_dict(),
                               model.electrode_areas_m2, info)
    return Calibration(model, gamma, names, theta, std, corr, basis, n_data, reference)
