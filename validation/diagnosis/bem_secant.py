"""A geometric candidate's fit made exact on the BEM where it was fitted: one re-solve of the changed scene.

The BEM's first derivatives (:mod:`.wall_gradient`, :mod:`.object_field`)
make a wall's or an object's small change as the BEM computes it; a large
one (a wall a few millimetres nearer a tip that is 1.5 cm from it, an
object within two of its radii of the sensor) leaves their second order to
the fast model. Here, once a candidate is fitted and its held-out
improvement is beyond the noise model's, its scene at the fitted parameters
``theta_hat`` is solved by the BEM at a dozen of the logged poses (both
ends of every pass, dense where the change is largest), and what the model
then still misses, ``c = log(I_bem / I_model)`` per receiver, is
interpolated along each pass and added to the candidate's prediction in
proportion to the parameters' projection on ``theta_hat``::

    log I(theta) = log I_model(theta) + c * (u . u_hat) / |u_hat|^2,    u = theta / scales,

exact at ``theta = 0`` (the baseline) and, at those poses, at ``theta_hat``.
The candidate is then fitted and scored again: its ranking, the verdict and
the gap after come from the BEM.

The poses are solved in two steps: first those where the candidate changes
the currents most, as many as a BEM check needs
(:func:`~.bem_check.check_pose_count`). The model's remaining error grows
with the change it predicts (its first order is the BEM's already); where it
is below ``enough`` (the caller: a tenth of the noise) at every one of those
poses, the rest is not solved: the correction is 0 there (the model), as at
poses where the change is negligible. (Interpolated from the first poses
alone, which crowd where the change is largest, a correction of that size
would be carried along a whole pass: measured on a test pass, it then
missed the full correction by 1.8 times the correction itself.)
A water depth fitted through the BEM's shape derivative is typically that
close (2e-5 against a noise of 5e-4 on the blind set-ups); an object near
the sensor is not. The tank of a changed scene is the
anchors' own tank mesh stretched to it (a mesh made anew would move K by
more than the correction); a sphere is meshed into it.

Example
-------
>>> import numpy as np
>>> s = SecantCorrection(np.array([1.0, 0.0]), np.ones((3, 2)))
>>> s.log_change(np.array([0.5, 0.3]), np.arange(3)).tolist()
[[0.5, 0.5], [0.5, 0.5], [0.5, 0.5]]
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["SecantCorrection", "stretched_tank_mesh", "bem_secant", "SECANT_POSES", "SECANT_ENOUGH"]

#: logged poses at which a candidate's fitted scene is solved (at least four a pass)
SECANT_POSES = 12
#: the model's misfit to the BEM, as a fraction of the noise, below which the first poses suffice (module doc)
SECANT_ENOUGH = 0.1


@dataclass
class SecantCorrection:
    """``c`` (P, m), the log-ratio of the BEM to the model at ``u_hat`` (scaled parameters), at every sample."""

    u_hat: np.ndarray
    c: np.ndarray

    def log_change(self, u: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(p, m) the correction of log I at samples ``idx`` for scaled parameters ``u``."""
        w = float(np.dot(u, self.u_hat) / np.dot(self.u_hat, self.u_hat)) if np.any(self.u_hat) else 0.0
        return w * self.c[np.asarray(idx)]


def stretched_tank_mesh(mesh, believed, tank):
    """``mesh`` of the ``believed`` box tank mapped onto ``tank`` (both in their own frames, centred): x and y
    scaled about the middle, z so that floor goes to floor and free surface to free surface."""
    v = np.array(mesh.vertices_m, float)
    for axis in (0, 1):
        v[:, axis] *= tank.size_m[axis] / believed.size_m[axis]
    f0, s0, f1, s1 = believed.floor_z_m, believed.free_surface_z_m, tank.floor_z_m, tank.free_surface_z_m
    v[:, 2] = f1 + (v[:, 2] - f0) * (s1 - f1) / (s0 - f0)
    return replace(mesh, vertices_m=v)


def bem_secant(problem, candidate, tank_mesh, bem_options: dict, n_poses: int = SECANT_POSES, progress=None,
               negligible: float = 0.0, enough: float = 0.0):
    """The :class:`SecantCorrection` of ``candidate`` (a :class:`~.select.CandidateScore` of one geometric
    effect) from the BEM of its fitted scene (module doc); ``tank_mesh``: the believed tank's mesh the anchors
    were solved on (None in unbounded water). Returns ``(correction, info)``.

    ``negligible`` (relative): a chosen pose where the candidate changes no current by more than this is not
    solved; the correction there is 0 (the caller passes the change below which no re-solve can move a
    prediction by a third of the noise: far from a fitted object, most of a pass).
    ``enough`` (relative): where the model is this close to the BEM at every pose of the first step, the
    other poses are not solved (module doc; 0: all are)."""
    from electrosense.bem import PoseSweep
    from electrosense.validation.diagnosis.bem_check import check_pose_count
    from electrosense.validation.diagnosis.effects import combined_scales
    from electrosense.validation.diagnosis.fitting import predict, scenario
    from electrosense.validation.diagnosis.forward import receiver_currents
    from electrosense.validation.diagnosis.multifidelity import choose_bem_poses
    from electrosense.validation.diagnosis.pose_gradient import along_passes, arc_length

    obs = problem.obs
    effects, theta = list(candidate.effects), np.asarray(candidate.fit.theta, float)
    every = np.arange(obs.n_poses)
    I_model = predict(problem, effects, theta, every)
    change = np.max(np.abs(I_model / problem.I_base - 1), axis=1)
    passes = obs.pass_indices()
    idx = np.unique(choose_bem_poses(change, passes, max(n_poses, 4 * len(passes))))
    solve = idx[change[idx] > negligible]
    first = np.sort(solve[np.argsort(-change[solve], kind="stable")][:check_pose_count(obs.n_receivers)])
    sc = scenario(problem, effects, theta, every)
    mesh = None
    if sc.tank is not None and tank_mesh is not None:
        mesh = stretched_tank_mesh(tank_mesh, obs.tank, sc.tank)
    I_bem = I_model.copy()   # the model itself where the change is negligible
    if len(solve):
        options = {k: v for k, v in bem_options.items() if k in ("edge_length_m",)}
        # at 1 S/m, as the anchors: K is linear in the water's conductivity (no contact impedance here; the
        # BEM's objects are insulators or perfect conductors), and the sensor's block and edge correction are
        # then the anchors' own, read back from the disk cache
        sweep = PoseSweep(obs.sensor, sc.tank, tuple(sc.objects), 1.0, tank_mesh=mesh,
                          focus_m=None if mesh is not None else sc.poses[solve, :3], **options)

        def solve_at(at):
            if progress:
                progress(f"{candidate.name}: its fitted scene solved by the BEM at {len(at)} poses"
                         + (f" ({len(idx) - len(solve)} more where it changes no current by more than "
                            f"{100 * negligible:.3g} %: correction 0)" if len(solve) < len(idx) and at is first else ""))
            K = sweep.conductance(sc.poses[at]).K_S * obs.sigma_S_per_m
            I_bem[at] = receiver_currents(K, obs.emitter) * obs.U_V[at, None]

        solve_at(first)
        misfit = float(np.max(np.abs(I_bem[first] / I_model[first] - 1)))
        rest = np.setdiff1d(solve, first)
        if len(rest) and misfit <= enough:
            if progress:
                progress(f"{candidate.name}: the model within {100 * misfit:.2g} % of the BEM where it changes the "
                         f"currents most: the other {len(rest)} poses not solved")
            solve = first   # the correction 0 at the others: the model there, as where the change is negligible
        elif len(rest):
            solve_at(rest)
    solved = np.isin(idx, solve)
    c_nodes = np.log(I_bem[idx] / I_model[idx])
    s = arc_length(obs.sensor, obs.poses, passes)
    c, loo = along_passes(c_nodes, idx, s, passes)
    u_hat = theta / combined_scales(effects)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    c_nodes, I_bem, idx = c_nodes[solved], I_bem[solve], solve   # the figures: where it was solved
    info = {"effect": candidate.name, "label": effects[0].label, "poses": idx.tolist(), "theta": theta.tolist(),
            "model_vs_bem_rms": rms(np.expm1(c_nodes)), "change_rms": rms(I_model[idx] / problem.I_base[idx] - 1),
            "loo_rms": rms(loo),
            # the bench against the baseline, the model and the BEM at these poses (in-sample RMS relative gaps)
            "gap_before": rms(problem.relative_residual(problem.I_base[idx], idx)),
            "gap_effect_model": rms(problem.relative_residual(I_model[idx], idx)),
            "gap_bem": rms(problem.relative_residual(I_bem, idx))}
    return SecantCorrection(u_hat, c), info
