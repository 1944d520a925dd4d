"""Instance transforms in numpy: which (4, 4) prototype-to-world matrices can be inverted, and the rigid
motion between two copies of one shape."""

from __future__ import annotations

import numpy as np

SINGULAR_DETERMINANT = 1e-12
"""|det| of a transform's 3x3 part below this, relative to its largest entry cubed, counts as singular:
a flattened instance, whose inverse would blow prototype-space distances up without bound."""


def invertible(transforms: np.ndarray) -> np.ndarray:
    """(I,) bool: finite (I, 4, 4) transforms whose 3x3 part is not (numerically) singular."""
    transforms = np.asarray(transforms, np.float64).reshape(-1, 4, 4)
    finite = np.isfinite(transforms).all(axis=(1, 2))
    safe = np.where(finite[:, None, None], transforms, np.eye(4))
    scale = np.abs(safe[:, :3, :3]).max(axis=(1, 2))
    return finite & (np.abs(np.linalg.det(safe[:, :3, :3])) > SINGULAR_DETERMINANT * np.maximum(scale, 1e-300) ** 3)


def rigid_alignment(source: np.ndarray, target: np.ndarray, *, tolerance: float) -> np.ndarray | None:
    """The proper rigid motion that takes ``source`` points onto ``target`` points, point i onto point i, or None
    when none does within ``tolerance``.

    Parameters
    ----------
    source, target : (P, 3) float64 corresponding points (the same mesh topology, in two frames)
    tolerance : largest distance allowed between a moved source point and its target (their units)

    Returns
    -------
    (4, 4) float64 row-vector matrix S (rotation R, det +1, then translation t): [source, 1] @ S ~ target,
    every point within ``tolerance``; the identity, exactly, when the points already agree within it, and a
    pure translation when one suffices. None for a reflection, a scale or another shape.

    Notes
    -----
    The rotation is the least-squares one of Kabsch (the orthogonal Procrustes problem, solved by the SVD of the
    cross-covariance) with the sign correction that keeps det R = +1 (Umeyama 1991, eq. 39-40); a match is then
    checked point by point, so symmetric or planar shapes, whose rotation is not unique, still match whenever
    some rotation fits. O(P).

    References
    ----------
    W. Kabsch, "A solution for the best rotation to relate two sets of vectors", Acta Cryst. A32 (1976) 922-923,
    doi:10.1107/S0567739476001873.
    S. Umeyama, "Least-squares estimation of transformation parameters between two point patterns", IEEE TPAMI
    13(4) (1991) 376-380, doi:10.1109/34.88573.
    """
    source = np.asarray(source, np.float64).reshape(-1, 3)
    target = np.asarray(target, np.float64).reshape(-1, 3)
    if source.shape != target.shape or not len(source) or not (np.isfinite(source).all() and np.isfinite(target).all()):
        return None
    motion = np.eye(4)

    def fits(matrix: np.ndarray) -> bool:
        moved = source @ matrix[:3, :3] + matrix[3, :3]
        return bool(np.sqrt(((moved - target) ** 2).sum(axis=1)).max() <= tolerance)

    if fits(motion):
        return motion
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    motion[3, :3] = target_mean - source_mean
    if fits(motion):
        return motion
    u, _, vt = np.linalg.svd((source - source_mean).T @ (target - target_mean))
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    motion[:3, :3] = u @ flip @ vt  # row vectors: source @ R ~ target
    motion[3, :3] = target_mean - source_mean @ motion[:3, :3]
    return motion if fits(motion) else None


def rotation_quaternion(rotation: np.ndarray) -> np.ndarray:
    """(4,) float64 unit quaternion (real, i, j, k) of a (3, 3) row-vector rotation R (v' = v @ R), in the
    convention of USD's ``xformOp:orient`` and Gf.Matrix3d(R).ExtractRotationQuat(); real part >= 0."""
    m = np.asarray(rotation, np.float64).T  # the column-vector matrix: v' = m @ v
    trace = np.trace(m)
    candidates = np.array([1.0 + trace, 1.0 + m[0, 0] - m[1, 1] - m[2, 2], 1.0 - m[0, 0] + m[1, 1] - m[2, 2],
                           1.0 - m[0, 0] - m[1, 1] + m[2, 2]])
    # Divide by the largest of 4w^2, 4x^2, 4y^2, 4z^2: no cancellation (S. W. Shepperd, "Quaternion from rotation
    # matrix", J. Guidance and Control 1(3) (1978) 223-224, doi:10.2514/3.55767b).
    k = int(np.argmax(candidates))
    s = 2.0 * np.sqrt(max(candidates[k], 0.0))
    if k == 0:
        q = [s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        q = [(m[2, 1] - m[1, 2]) / s, s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s]
    else:
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q
