"""The coordinates a tank map interpolates in: poses folded by the tank's symmetry, cap centres warped near walls.

Three facts make the BEM's K far easier to interpolate than it looks in (x, y, heading):

1. **symmetry**: the sensor is a body of revolution, so a mirror plane of the
   tank through its axis maps a pose onto one with the same K. A box tank
   has two (x -> -x with heading -> pi - heading, y -> -y with heading ->
   -heading), a square one a third (x <-> y); a cylindrical tank is invariant
   under every rotation about its axis and one mirror, which leaves two
   numbers per depth: the sensor's centre in the frame of its own axis,
   (x', |y'|). Every pose is *folded* into the fundamental domain before it
   is interpolated, which quarters (box) the space the BEM must cover, or
   takes away a dimension (cylinder). Fixed objects break the symmetry: a
   scene with objects is not folded. A sensor with sectors is a body of
   revolution only in shape: a reflection maps it onto its mirror image, whose
   sectors are permuted (:meth:`MapFrame.reflected`, the map permutes K back),
   and with a ring in an odd number of sectors onto no sensor at all; then only
   a cylinder's rotations fold.
2. **the walls**: K changes fastest where a cap comes near a wall (tens of
   percent between 5 mm and 2 cm). The features are the two end caps' centres,
   each coordinate *warped* so that distance from the nearest wall counts
   logarithmically below a scale ``warp_m``: u -> +-(c log(1 + h/c) -
   c log(1 + s/c)) with s the distance from the nearer wall (caps' radius
   taken off) and h half the span. Odd, smooth, with slope 1 / (1 + s/c).

3. **the walls' images**: K's change near a wall is, to leading order, the
   electrodes' mirror images in it (:meth:`MapFrame.wall_images`), which the
   map may take as linear regressors beside its radial basis functions.

4. **the fold's faces**: an interpolant over folded nodes has nodes on one
   side of each mirror plane only, and errs there as at any edge of its
   nodes; a node near a face lends it its mirror image
   (:meth:`MapFrame.mirror_ghosts`), so the plane is inside the nodes again.

Folded and warped, a cubic RBF on 60 BEM poses of a 4-electrode sensor in a
0.6 x 0.5 x 0.4 m box came 10x closer to the BEM at fresh poses (tips 5 mm to
17 cm from a wall) than on the bare tip positions: 0.54 % RMS against 5.6 %.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.tank import Tank
>>> frame = MapFrame(preset("angels-4"), Tank((1.0, 1.0, 1.0)))
>>> P = np.array([[0.2, 0.1, 0.0, 0.3], [-0.2, 0.1, 0.0, np.pi - 0.3], [0.1, 0.2, 0.0, np.pi / 2 - 0.3]])
>>> F = frame.features(P)
>>> bool(np.allclose(F[0], F[1]) and np.allclose(F[0], F[2]))   # mirror images and the square's swap
True
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MapFrame", "object_image", "warp", "DEFAULT_WARP_M"]

#: the warp's length scale (m): below it, distance from a wall counts logarithmically (chosen on BEM data: the
#: error at fresh poses was flat from 0.3 to 1 mm and grew above: 0.54, 0.66, 0.78 % RMS at 1, 3, 5 mm, 1.1 % at
#: 10 mm, 4.0 % at 100 mm)
DEFAULT_WARP_M = 0.001

#: a mirror image of a node nearer than this many times the node's spacing to any node is left out
#: (:meth:`MapFrame.mirror_ghosts`): a quintic kernel's matrix is near singular for two close nodes
GHOST_MIN_GAP = 0.5


def object_image(obj, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point's image in a fixed object and the image's strength: (..., 3) and (...).

    A ball of radius ``a`` about ``c``: Kelvin's inverse point ``c + a^2 (p - c) / |p - c|^2``, strength
    ``a / |p - c|`` (a point current's image in a conducting ball; the insulating ball's leading image is the
    same point); a vertical pole: the point inverted in the pole's circle at its height, strength 1; a box: the
    point mirrored in the plane of its nearest face (clamped to the box), strength 1.

    >>> from electrosense.meshes.objects import Sphere
    >>> q, w = object_image(Sphere((0.0, 0.0, 0.0), radius_m=0.1), np.array([[0.2, 0.0, 0.0]]))
    >>> q.round(6).tolist(), w.tolist()
    ([[0.05, 0.0, 0.0]], [0.5])
    """
    from electrosense.meshes.objects import Cylinder, Sphere

    c = np.asarray(obj.centre_m, float)
    p = np.asarray(points_m, float) - c
    if isinstance(obj, Sphere):
        d2 = np.sum(p**2, axis=-1)
        return c + (obj.radius_m**2 / d2)[..., None] * p, obj.radius_m / np.sqrt(d2)
    if isinstance(obj, Cylinder):
        f = obj.radius_m**2 / (p[..., 0] ** 2 + p[..., 1] ** 2)
        return c + np.stack([f * p[..., 0], f * p[..., 1], p[..., 2]], axis=-1), np.ones(p.shape[:-1])
    cs, sn = np.cos(obj.yaw_rad), np.sin(obj.yaw_rad)     # a box: in its own frame, mirrored in its nearest face
    u = np.stack([cs * p[..., 0] + sn * p[..., 1], -sn * p[..., 0] + cs * p[..., 1], p[..., 2]], axis=-1)
    half = 0.5 * np.asarray(obj.size_m, float)
    m = 2.0 * np.clip(u, -half, half) - u
    return c + np.stack([cs * m[..., 0] - sn * m[..., 1], sn * m[..., 0] + cs * m[..., 1], m[..., 2]], axis=-1), \
        np.ones(p.shape[:-1])


def warp(u: np.ndarray, lo, hi, c: float) -> tuple[np.ndarray, np.ndarray]:
    """The warped coordinate of ``u`` in [lo, hi] and its derivative (module doc); 0 at the middle.

    >>> w, dw = warp(np.array([0.0, 0.5, 0.999]), -1.0, 1.0, 0.01)
    >>> w.round(4).tolist(), dw.round(4).tolist()
    ([0.0, 0.0068, 0.0452], [0.0099, 0.0196, 0.9091])
    """
    u = np.asarray(u, float)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    h = 0.5 * (hi - lo)
    s_lo, s_hi = np.maximum(u - lo, 0.0), np.maximum(hi - u, 0.0)
    top = c * np.log1p(h / c)
    lower = u <= lo + h
    w = np.where(lower, c * np.log1p(s_lo / c) - top, top - c * np.log1p(s_hi / c))
    dw = 1.0 / (1.0 + np.where(lower, s_lo, s_hi) / c)
    return w, dw


@dataclass(frozen=True)
class MapFrame:
    """Folding and features of poses for one sensor in one tank (box or cylinder) with fixed ``objects``.

    ``band``: the map covers a band of depths (z is then a feature, warped
    towards the floor and the free surface); ``warp_m``: the warp's scale.
    """

    sensor: object
    tank: object
    objects: tuple = ()
    band: bool = False
    warp_m: float = DEFAULT_WARP_M

    @property
    def cylinder(self) -> bool:
        return hasattr(self.tank, "radius_m")

    @property
    def symmetric(self) -> bool:
        """Folded by the tank's mirror planes (not with fixed objects, which break them)."""
        return not self.objects

    @property
    def mirrors(self) -> bool:
        """Folded by reflections too: the sensor has a mirror image (no ring split into an odd number of sectors,
        :meth:`~electrosense.meshes.sensor.SensorDescription.lateral_mirror`); a cylinder's rotations need none."""
        return self.symmetric and self.sensor.lateral_mirror() is not None

    @property
    def square(self) -> bool:
        """A box with a square floor: folded across its diagonal too."""
        return not self.cylinder and abs(self.tank.size_m[0] - self.tank.size_m[1]) < 1e-12

    def _box_fold(self, x, y):
        """(sx, sy, swap) of a box's fold: the signs that reflect x and y into x, y >= 0, then, in a square tank,
        the swap of x and y across its diagonal; no reflection where :attr:`mirrors` is False."""
        P = len(x)
        if not self.mirrors:
            return np.ones(P), np.ones(P), np.zeros(P, bool)
        sx, sy = np.where(x < 0, -1.0, 1.0), np.where(y < 0, -1.0, 1.0)
        return sx, sy, (np.abs(y) > np.abs(x)) & self.square

    def _cylinder_side(self, x, y, yaw):
        """(P,) -1 where a cylinder's fold reflects the pose (the sensor's centre on its own -y side), else 1."""
        v = -x * np.sin(yaw) + y * np.cos(yaw)
        return np.where((v < 0) & self.mirrors, -1.0, 1.0)

    def reflected(self, poses) -> np.ndarray:
        """(P,) bool: the fold of each pose reflects it (an odd number of mirror planes): its K is the folded
        pose's with the electrodes permuted by the sensor's lateral mirror (the identity without sectors)."""
        p = np.asarray(poses, float).reshape(-1, 4)
        x, y, yaw = p[:, 0], p[:, 1], p[:, 3]
        if self.cylinder:
            return self._cylinder_side(x, y, yaw) < 0
        sx, sy, swap = self._box_fold(x, y)
        return (sx * sy < 0) ^ swap

    def folded(self, poses) -> np.ndarray:
        """(P, 4) the poses folded into the fundamental domain: the pose of each one's orbit under the tank's
        symmetries at which the map was solved (same features; the identity where nothing folds).

        >>> from electrosense.meshes import preset
        >>> from electrosense.meshes.tank import Tank
        >>> frame = MapFrame(preset("angels-4"), Tank((1.0, 0.8, 1.0)))
        >>> P = np.array([[-0.2, 0.1, 0.0, 0.3], [0.1, -0.3, 0.0, 2.0]])
        >>> Q = frame.folded(P)
        >>> bool((Q[:, :2] >= 0).all()), bool(np.allclose(frame.features(Q), frame.features(P)))
        (True, True)
        """
        p = np.array(poses, float).reshape(-1, 4)
        if not self.symmetric:
            return p
        x, y, yaw = p[:, 0], p[:, 1], p[:, 3]
        if self.cylinder:    # turned about the axis to heading 0, then reflected onto the +y side
            c, s = np.cos(yaw), np.sin(yaw)
            return np.c_[x * c + y * s, self._cylinder_side(x, y, yaw) * (-x * s + y * c), p[:, 2], np.zeros(len(p))]
        sx, sy, swap = self._box_fold(x, y)
        u, v = sx * x, sy * y
        hx, hy = np.cos(yaw) * sx, np.sin(yaw) * sy         # the heading reflected with the position
        u, v, hx, hy = np.where(swap, v, u), np.where(swap, u, v), np.where(swap, hy, hx), np.where(swap, hx, hy)
        return np.c_[u, v, p[:, 2], np.arctan2(hy, hx)]

    def mirror_ghosts(self, F: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mirror images of nodes across the fundamental domain's faces, in features: ``(F_ghost, source, odd)``.

        The fold (:meth:`folded`) cuts the pose space along the tank's mirror planes, and an interpolant over
        the folded nodes has nodes on one side of each cut only: it extrapolates there, as at the edge of any
        node set, though the BEM's K goes on smoothly across the plane (seed 4's box: a tip 5 mm from a wall
        on the plane y = 0 erred 0.08-0.10 %, at 6-18 cm from it 0.004-0.021 %). A node's mirror image across a
        face has the node's K (the electrodes permuted by the sensor's lateral mirror where the image is
        reflected, ``odd``) and in features it is the node with its lateral coordinates negated (a box's y = 0
        and x = 0 planes, and their product near the box's centre line), or its two coordinates swapped (a
        square's diagonal), or its centre's offset from the axis negated (a cylinder). Those within ``reach``
        times the node's distance to its nearest other node are returned, ``source`` the index of their node,
        but none nearer any node than :data:`GHOST_MIN_GAP` times that distance (a node on or close to the face
        is its own image there, and two close nodes make a quintic kernel's matrix near singular).

        >>> from electrosense.meshes import preset
        >>> from electrosense.meshes.tank import Tank
        >>> frame = MapFrame(preset("angels-4"), Tank((1.0, 0.8, 1.0)))
        >>> F = frame.features(np.array([[0.3, 0.02, 0.0, 0.0], [0.3, 0.06, 0.0, 0.0], [0.35, 0.0, 0.0, 0.0]]))
        >>> G, source, odd = frame.mirror_ghosts(F, reach=2.0)
        >>> source.tolist(), odd.tolist()       # the node 2 cm off y = 0 only: the last lies on it
        ([0], [True])
        >>> G_pose = frame.features(np.array([[0.3, -0.02, 0.0, 0.0]]), fold=False)
        >>> bool(np.allclose(G, G_pose))
        True
        """
        F = np.asarray(F, float)
        if not self.symmetric or not self.mirrors or len(F) < 2:
            return np.zeros((0, F.shape[1])), np.zeros(0, int), np.zeros(0, bool)
        from scipy.spatial import cKDTree

        def negate(cols):
            def image(A):
                A = A.copy()
                A[:, cols] *= -1.0
                return A
            return image

        def swap(A):
            A = A.copy()
            A[:, [0, 1, 2, 3]] = A[:, [1, 0, 3, 2]]
            return A

        lateral = negate([1, 3])
        if self.cylinder:
            images = [(lateral, True)]
        elif self.square:   # faces y = 0 and y = x
            images = [(lateral, True), (swap, True), (lambda A: swap(lateral(A)), False)]
        else:
            images = [(lateral, True), (negate([0, 2]), True), (negate([0, 1, 2, 3]), False)]
        tree = cKDTree(F)
        spacing = tree.query(F, k=2)[0][:, 1]
        out, source, odd = [np.zeros((0, F.shape[1]))], [np.zeros(0, int)], [np.zeros(0, bool)]
        for image, reflects in images:
            G = image(F)
            d = np.linalg.norm(G - F, axis=1)
            keep = np.flatnonzero((d < reach * spacing) & (tree.query(G)[0] >= GHOST_MIN_GAP * spacing))
            out.append(G[keep])
            source.append(keep)
            odd.append(np.full(len(keep), reflects))
        return np.vstack(out), np.concatenate(source), np.concatenate(odd)

    @property
    def n_features(self) -> int:
        return 4 + int(self.band)

    def _cap_offset_m(self) -> float:
        return 0.5 * self.sensor.length_m - self.sensor.radius_m

    def features(self, poses, jacobian: bool = False, fold: bool = True):
        """(P, d) features of ``poses`` (P, 4); with ``jacobian`` also d features / d(x, y, yaw), (P, d, 3);
        ``fold=False``: of the poses as they are, not folded (:meth:`mirror_ghosts`)."""
        p = np.asarray(poses, float).reshape(-1, 4)
        x, y, z, yaw = p.T
        a, r = self._cap_offset_m(), self.sensor.radius_m
        c = self.warp_m
        P = len(p)
        if self.cylinder:
            if self.symmetric:   # the sensor's own frame: rotated by -yaw, mirrored to y' >= 0
                cs, sn = np.cos(yaw), np.sin(yaw)
                u, v = x * cs + y * sn, -x * sn + y * cs
                sgn = self._cylinder_side(x, y, yaw) if fold else np.ones(P)
                v = sgn * v
                # d(u, v)/d(x, y, yaw)
                du = np.stack([cs, sn, v * sgn], axis=-1)
                dv = sgn[:, None] * np.stack([-sn, cs, -u], axis=-1)
                centres = [(u + a, v), (u - a, v)]
                d_centres = [(du, dv), (du, dv)]
            else:
                cs, sn = np.cos(yaw), np.sin(yaw)
                centres = [(x + a * cs, y + a * sn), (x - a * cs, y - a * sn)]
                one, zero = np.ones(P), np.zeros(P)
                d_centres = [(np.stack([one, zero, -a * sn], -1), np.stack([zero, one, a * cs], -1)),
                             (np.stack([one, zero, a * sn], -1), np.stack([zero, one, -a * cs], -1))]
            R = np.asarray(self.tank.radius_at(z), float) - r
            R = np.broadcast_to(R, (P,))
            cols, dcols = [], []
            for (px, py), (dpx, dpy) in zip(centres, d_centres):
                rho = np.hypot(px, py)
                w, dw = warp(rho, -R, R, c)   # odd in rho: w(0) = 0
                g = np.where(rho > 1e-12, w / np.maximum(rho, 1e-12), dw)   # scale factor w / rho
                # d(g p)/dp = g I + p p^T (dw - g) / rho^2
                k = np.where(rho > 1e-12, (dw - g) / np.maximum(rho, 1e-12) ** 2, 0.0)
                cols += [g * px, g * py]
                if jacobian:
                    Jx = (g + k * px * px)[:, None] * dpx + (k * px * py)[:, None] * dpy
                    Jy = (k * px * py)[:, None] * dpx + (g + k * py * py)[:, None] * dpy
                    dcols += [Jx, Jy]
        else:
            lo, hi = self.tank.water_bounds_m
            sx, sy, swap = self._box_fold(x, y) if fold else (np.ones(P), np.ones(P), np.zeros(P, bool))
            x, y = sx * x, sy * y
            yaw = np.where(sx < 0, np.pi - yaw, yaw)
            yaw = np.where(sy < 0, -yaw, yaw)
            x, y = np.where(swap, y, x), np.where(swap, x, y)
            yaw = np.where(swap, 0.5 * np.pi - yaw, yaw)
            cs, sn = np.cos(yaw), np.sin(yaw)
            cols, dcols = [], []
            for sign in (1.0, -1.0):
                wx, dwx = warp(x + sign * a * cs, lo[0] + r, hi[0] - r, c)
                wy, dwy = warp(y + sign * a * sn, lo[1] + r, hi[1] - r, c)
                cols += [wx, wy]
                if jacobian:   # in the folded pose's coordinates (x, y, yaw)
                    zero = np.zeros(P)
                    dcols += [dwx[:, None] * np.stack([np.ones(P), zero, -sign * a * sn], -1),
                              dwy[:, None] * np.stack([zero, np.ones(P), sign * a * cs], -1)]
            if jacobian:   # back to the original pose: the fold is linear, d(folded)/d(pose) per pose
                T = np.zeros((P, 3, 3))
                T[:, 0, 0], T[:, 1, 1] = sx, sy
                T[:, 2, 2] = np.where(sx * sy < 0, -1.0, 1.0)
                S = np.tile(np.eye(3), (P, 1, 1))
                S[swap] = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])
                T = S @ T
                dcols = [np.einsum("pk,pkj->pj", d, T) for d in dcols]
        if self.band:
            lo_z = self.tank.floor_z_m + r
            hi_z = self.tank.free_surface_z_m - r
            wz, _ = warp(z, lo_z, hi_z, c)
            cols.append(wz)
            dcols.append(np.zeros((P, 3)))
        # one scale for every feature (distances keep their ratios): O(1) values keep the RBF well conditioned
        scale = 1.0 / self.feature_scale_m
        F = scale * np.stack(cols, axis=-1)
        if not jacobian:
            return F
        return F, scale * np.stack(dcols, axis=1)

    @property
    def axial_positions_m(self) -> np.ndarray:
        """The sensor's distinct axial electrode positions (m, sensor frame), increasing: a ring's sectors share one."""
        return np.unique(np.round(self.sensor.electrode_centres_m[:, 0], 12))

    @property
    def n_image_groups(self) -> int:
        """The groups of :meth:`wall_images`: in a box the walls (and a band's floor and free surface) and the
        vertical edges, each its own regressors; in a cylinder one."""
        return 1 if self.cylinder else 2

    @property
    def n_wall_images(self) -> int:
        """The number of :meth:`wall_images` regressors: one per two axial positions ``a <= b`` and image group,
        and as many per fixed object (:meth:`object_images`)."""
        k = len(self.axial_positions_m)
        return (self.n_image_groups + len(self.objects)) * k * (k + 1) // 2

    def _axial_points(self, poses):
        """(P, k, 3) the sensor's distinct axial electrode positions at ``poses`` (P, 4), and their d(x, y) /
        d(x, y, yaw), (P, k, 2, 3)."""
        p = np.asarray(poses, float).reshape(-1, 4)
        x, y, z, yaw = p.T
        u = self.axial_positions_m
        k = len(u)
        cs, sn = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        pts = np.stack([x[:, None] + u * cs, y[:, None] + u * sn, np.repeat(z[:, None], k, axis=1)], axis=-1)
        dpts = np.zeros((len(p), k, 2, 3))          # z is no parameter
        dpts[:, :, 0, 0] = dpts[:, :, 1, 1] = 1.0
        dpts[:, :, 0, 2], dpts[:, :, 1, 2] = -u * sn, u * cs
        return pts, dpts

    def object_images(self, poses, jacobian: bool = False):
        """The fixed objects' images as regressors, (P, objects * k (k + 1) / 2), one group per object; with
        ``jacobian`` also their d/d(x, y, yaw) (central differences, 1 um and 1 urad: the images are smooth
        where the map has poses), (P, 3, r).

        For each two axial electrode positions ``a <= b``, ``L w_b / |p_a - q_b|`` symmetrised, with ``q_b, w_b``
        the point ``p_b``'s image in the object (:func:`object_image`: Kelvin's in a ball, its inverse in a
        pole's circle, its mirror in a box's nearest face) and ``L`` the sensor's length: the leading change of
        K by an object near the sensor, in a form the map need only scale. Without them a map of a random
        4-electrode sensor in a box with a conducting ball and an insulating pole (310 BEM poses) erred
        2.6 % RMS at fresh poses; refitted on the same nodes with them, 0.30 %.

        >>> from electrosense.meshes import preset
        >>> from electrosense.meshes.objects import Sphere
        >>> from electrosense.meshes.tank import Tank
        >>> frame = MapFrame(preset("angels-4"), Tank((1.0, 1.0, 1.0)), (Sphere((0.3, 0.0, 0.0), radius_m=0.03),))
        >>> R = frame.object_images(np.array([[0.0, 0, 0, 0], [0.1, 0, 0, 0], [0.0, 0.2, 0, 0]]))
        >>> R.shape, bool(R[1, 0] > R[0, 0] > R[2, 0] > 0)
        ((3, 10), True)
        """
        p = np.asarray(poses, float).reshape(-1, 4)
        if not self.objects:
            R = np.zeros((len(p), 0))
            return (R, np.zeros((len(p), 3, 0))) if jacobian else R
        k = len(self.axial_positions_m)
        ia, ib = np.triu_indices(k)

        def regressors(Q):
            pts, _ = self._axial_points(Q)
            cols = []
            for obj in self.objects:
                q, w = object_image(obj, pts)                                              # (P, k, 3), (P, k)
                A = w[:, None, :] / np.linalg.norm(pts[:, :, None, :] - q[:, None, :, :], axis=-1)   # (P, a, b)
                cols.append(0.5 * (A + A.transpose(0, 2, 1))[:, ia, ib])
            return self.sensor.length_m * np.concatenate(cols, axis=1)

        R = regressors(p)
        if not jacobian:
            return R
        dR = np.zeros((len(p), 3, R.shape[1]))
        for j, (c, h) in enumerate(((0, 1e-6), (1, 1e-6), (3, 1e-6))):
            up, down = p.copy(), p.copy()
            up[:, c] += h
            down[:, c] -= h
            dR[:, j] = (regressors(up) - regressors(down)) / (2 * h)
        return R, dR

    def wall_images(self, poses, jacobian: bool = False):
        """The walls' images as regressors: (P, r), with ``jacobian`` also their d/d(x, y, yaw), (P, 3, r).

        For each two of the sensor's distinct axial electrode positions ``a <= b`` (sectors of one ring share
        theirs) and each group of images, ``L sum_w 1 / |p_a - M_w p_b|``, symmetrised: the sum over the
        group's mirror images ``M_w`` of a point current's inverse distance to the other's image
        (:mod:`electrosense.psm.images`), times the sensor's length ``L``; the groups one after the other
        (:attr:`n_image_groups`). A point current's image in an insulating plane is the leading wall
        effect on K, and it grows like one over the gap: what the interpolant finds hardest near a wall, in
        a form it need only scale (:class:`TankMap` fits it as linear regressors beside the radial basis
        functions where their leave-one-out errors favour it). A box: its four walls and four vertical edges
        (the paper's eight images), and the floor and free surface in a band, the edges' images (a wall's image in
        the next wall) a group of their own: with one coefficient for all, a sensor in a corner took the edge's
        image at a single wall's weight (refitted on the nodes of five studies' maps, the split took a corner pose's error
        from 0.156 % to 0.110 % and the poses 5-15 mm from a wall from 0.046 % / 0.123 % to 0.033 % / 0.068 %);
        a cylinder: each point mirrored across the wall along its radius (the tangent plane's image), and the
        floor and free surface in a band. Fixed objects' images follow, a group each (:meth:`object_images`).
        Invariant under the tank's symmetries, like K.

        >>> from electrosense.meshes import preset
        >>> from electrosense.meshes.tank import Tank
        >>> frame = MapFrame(preset("angels-4"), Tank((1.0, 1.0, 1.0)))
        >>> R = frame.wall_images(np.array([[0.0, 0, 0, 0], [0.3, 0, 0, 0], [-0.3, 0, 0, np.pi]]))
        >>> R.shape, bool(R[1, 0] > R[0, 0]), bool(np.allclose(R[1], R[2]))
        ((3, 20), True, True)
        """
        from electrosense.psm.images import paper8_images

        p = np.asarray(poses, float).reshape(-1, 4)
        P = len(p)
        k = len(self.axial_positions_m)
        pts, dpts = self._axial_points(p)
        lo, hi = self.tank.water_bounds_m
        if self.cylinder:   # images (I, P, k, 3) and their (x, y) derivatives (I, P, k, 2, 3)
            rho = np.maximum(np.hypot(pts[..., 0], pts[..., 1]), 1e-12)
            R2 = 2.0 * np.asarray(self.tank.radius_at(pts[..., 2]), float)
            f = R2 / rho - 1.0                 # the radius mirrored across the wall: rho -> 2 R - rho
            q = [pts * np.stack([f, f, np.ones_like(f)], axis=-1)]
            drho = np.einsum("pkc,pkcj->pkj", pts[..., :2], dpts) / rho[..., None]
            dq = [f[..., None, None] * dpts - (R2 / rho**2)[..., None, None] * pts[..., :2, None] * drho[..., None, :]]
            if self.band:                      # floor and free surface: planes, x and y unchanged
                q += [pts * [1.0, 1.0, -1.0] + [0.0, 0.0, 2.0 * b] for b in (lo[2], hi[2])]
                dq += [dpts, dpts]
            q, dq, isometric = np.stack(q), np.stack(dq), False
            group = np.zeros(len(q), int)
        else:               # affine images x -> signs x + offsets
            imgs = paper8_images(self.tank)
            signs, offsets = imgs.signs, imgs.offsets_m
            group = (np.sum(signs[:, :2] < 0, axis=1) == 2).astype(int)   # 0: a wall, 1: an edge (two walls)
            if self.band:                      # and the floor's and the free surface's
                signs = np.vstack([signs, [[1.0, 1.0, -1.0]] * 2])
                offsets = np.vstack([offsets, [[0.0, 0.0, 2.0 * lo[2]], [0.0, 0.0, 2.0 * hi[2]]]])
                group = np.r_[group, 0, 0]
            s_ = signs[:, None, None, :]
            q = s_ * pts + offsets[:, None, None, :]
            dq, isometric = s_[..., :2, None] * dpts, True
        # pairs a <= b; an isometric image gives |p_a - M p_b| = |p_b - M p_a|, else both orders are summed
        ia, ib = np.triu_indices(k)
        orders = [(ia, ib)] if isometric else [(ia, ib), (ib, ia)]
        w = 1.0 / len(orders)
        G = self.n_image_groups
        R = np.zeros((P, G, len(ia)))
        dR = np.zeros((P, 3, G, len(ia)))
        for a, b in orders:
            diff = pts[None][:, :, a] - q[:, :, b]                              # (I, P, pairs, 3)
            inv = 1.0 / np.sqrt(np.sum(diff**2, axis=-1))
            for g in range(G):
                R[:, g] += np.sum(w * inv[group == g], axis=0)
            if jacobian:   # -w diff . (d p_a - d q_b) / dist^3
                w3 = w * inv**3
                dpa, dqb = dpts[:, a], dq[:, :, b]
                for j in range(3):
                    dd = sum(diff[..., c] * (dpa[None, ..., c, j] - dqb[..., c, j]) for c in (0, 1))
                    for g in range(G):
                        dR[:, j, g] -= np.sum((w3 * dd)[group == g], axis=0)
        R, dR = R.reshape(P, -1), dR.reshape(P, 3, -1)
        L = self.sensor.length_m
        if not self.objects:
            return (L * R, L * dR) if jacobian else L * R
        if not jacobian:
            return np.hstack([L * R, self.object_images(p)])
        Ro, dRo = self.object_images(p, jacobian=True)
        return np.hstack([L * R, Ro]), np.concatenate([L * dR, dRo], axis=2)

    @property
    def feature_scale_m(self) -> float:
        """The warped half-span of the tank's widest dimension (features are divided by it)."""
        lo, hi = self.tank.water_bounds_m
        h = 0.5 * float(np.max(hi - lo))
        return float(self.warp_m * np.log1p(h / self.warp_m))
