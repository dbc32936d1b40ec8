"""Frame conventions between RotorPy and our bridge, and the rotation helpers both sides use.

RotorPy 3.0.0 (``rotorpy.vehicles.multirotor.Multirotor``):

- world frame: z **up**; gravity is ``[0, 0, -m g]`` (``Multirotor.weight``). RotorPy names no
  horizontal axes; we read x as East and y as North, i.e. **ENU**. Nothing in the physics
  depends on which horizontal axis is North (no magnetometer, no wind here), so this reading is
  a free choice, but it must be a *proper* rotation away from NED, and ENU is;
- body frame: x forward, y left, z up (**FLU**): every rotor thrusts along body +z
  (``compute_body_wrench``), the Hummingbird's rotor 1 sits at (+x, +y) = front left;
- attitude: quaternion ``[i, j, k, w]`` (scalar last, scipy's order) rotating body coordinates
  into world coordinates (``Ftot = R @ FtotB``);
- ``state['w']`` is the body rate in body (FLU) axes; ``state['v']`` the CoG velocity in world
  (ENU) axes.

Our bridge (docs/sim-bridge.md): world **NED**, body **FRD**. The two changes of axes are

- ``C_NED_ENU``: (north, east, down) = (y_enu, x_enu, -z_enu), determinant +1;
- ``C_FRD_FLU``: (x, y, z)_frd = (x, -y, -z)_flu, determinant +1 (a half turn about x).

Both matrices are symmetric and their own inverse. A rotation ``R_enu_flu`` (body FLU to world
ENU) becomes ``R_ned_frd = C_NED_ENU @ R_enu_flu @ C_FRD_FLU``.
"""

import math

import numpy as np

#: ENU coordinates -> NED coordinates (and back: it is its own inverse).
C_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: FLU coordinates -> FRD coordinates (and back: it is its own inverse).
C_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def rotation_from_quat_xyzw(q):
    """Rotation matrix of a unit quaternion in RotorPy's order ``[i, j, k, w]`` (Hamilton).

    Written out instead of ``scipy.spatial.transform.Rotation`` because it runs four times per
    integration step and scipy's object costs ten times more.
    """
    x, y, z, w = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    return np.array(
        [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
            [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
            [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
        ]
    )


def quat_xyzw_from_rotation(rot):
    """Unit quaternion ``[i, j, k, w]`` of a rotation matrix (Shepperd's method)."""
    m = np.asarray(rot, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    q = np.array(q)
    return q / np.linalg.norm(q)


def rotation_about(axis, angle_rad):
    """Rotation matrix by ``angle_rad`` about ``axis`` (any length), right-handed (Rodrigues)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * (k @ k)


def ned_from_enu(v_enu):
    """A world vector from RotorPy's ENU coordinates to NED."""
    return C_NED_ENU @ np.asarray(v_enu, dtype=float)


def enu_from_ned(v_ned):
    """A world vector from NED coordinates to RotorPy's ENU."""
    return C_NED_ENU @ np.asarray(v_ned, dtype=float)


def frd_from_flu(v_flu):
    """A body vector from RotorPy's FLU axes to FRD."""
    return C_FRD_FLU @ np.asarray(v_flu, dtype=float)


def flu_from_frd(v_frd):
    """A body vector from FRD axes to RotorPy's FLU."""
    return C_FRD_FLU @ np.asarray(v_frd, dtype=float)


def r_ned_frd(r_enu_flu):
    """The attitude (body FRD -> world NED) of a RotorPy attitude (body FLU -> world ENU)."""
    return C_NED_ENU @ r_enu_flu @ C_FRD_FLU


def r_enu_flu(r_ned_frd_):
    """RotorPy's attitude (body FLU -> world ENU) of an attitude body FRD -> world NED."""
    return C_NED_ENU @ r_ned_frd_ @ C_FRD_FLU


def heading_rad(r_ned_frd_):
    """Heading as our pose field means it: the yaw of the body frame about world down, rad.

    The angle from north to the body x axis projected on the horizontal plane, positive towards
    east, as ``sim::recovery::heading`` computes it (``atan2`` of the x axis' east and north
    components).
    """
    return math.atan2(r_ned_frd_[1, 0], r_ned_frd_[0, 0])
