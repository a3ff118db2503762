"""The pinhole projection's Jacobian for a small motion of the camera, shared by every pose refinement
that reprojects map points (the screening's reference pose, the features joined to a depth alignment).

A camera point ``X = (x, y, z)`` projects to ``u = fx x / z + cx``, ``v = fy y / z + cy``. Moved on the
left by ``(omega, nu)`` (``X <- Exp(omega) X + nu``; to first order ``dX = -[X]_x omega + nu``), with
``a = x / z`` and ``b = y / z``::

    du = fx (-a b  omega_x + (1 + a^2) omega_y - b omega_z + nu_x / z - a nu_z / z)
    dv = fy (-(1 + b^2) omega_x + a b omega_y + a omega_z + nu_y / z - b nu_z / z)

(Barfoot 2017, "State Estimation for Robotics", the camera's Jacobian written out.)
"""

from __future__ import annotations

import numpy as np

__all__ = ["projection_jacobian"]


def projection_jacobian(X: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(J (6, 2M), x/z, y/z)``: the Jacobian of the pixels of the camera points ``X (3, M)`` (in front of
    the camera) for a left perturbation ``(omega, nu)`` of the pose (module docstring), the ``u`` rows of
    every point first, then the ``v`` rows; one matrix, so that ``J W J^T`` is one product."""
    fx, fy = K[0, 0], K[1, 1]
    m = X.shape[1]
    iz = 1.0 / X[2]
    xz, yz = X[0] * iz, X[1] * iz
    J = np.zeros((6, 2 * m))
    ju, jv = J[:, :m], J[:, m:]
    xy = xz * yz
    np.multiply(xy, -fx, out=ju[0])
    np.multiply(xy, fy, out=jv[1])
    t = xz * xz
    t += 1.0
    np.multiply(t, fx, out=ju[1])
    t = yz * yz
    t += 1.0
    np.multiply(t, -fy, out=jv[0])
    np.multiply(yz, -fx, out=ju[2])
    np.multiply(xz, fy, out=jv[2])
    np.multiply(iz, fx, out=ju[3])
    np.multiply(iz, fy, out=jv[4])
    np.multiply(xz * iz, -fx, out=ju[5])
    np.multiply(yz * iz, -fy, out=jv[5])
    return J, xz, yz
