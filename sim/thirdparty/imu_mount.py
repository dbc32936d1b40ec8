"""The IMU: mounted at an offset from the CoG, rotated, averaged to the 2 kHz control rate, noisy.

What a body-mounted accelerometer at ``r`` (from the CoG) measures is the specific force of its
own point, in its own axes:

    f_imu = M [ Rᵀ (a_cog − g) + Ω̇ × r + Ω × (Ω × r) ]        gyro_imu = M Ω

with ``R`` the attitude (body -> world), ``a_cog`` the CoG acceleration (world), ``g`` gravity
(world), ``Ω``, ``Ω̇`` the body rate and angular acceleration (body axes) and ``M`` the rotation
from body FRD axes to IMU axes. It is evaluated in RotorPy's FLU body axes (``r`` converted
once) and turned into IMU axes through FRD.

Decimation: the board's driver averages the 8 kHz samples of each 0.5 ms control period. We take
the exact average over the period instead of four point samples: the integrator's four RK4 stages
(start, two midpoints, end, weights 1, 2, 2, 1 over 6) are Simpson's rule for that average, so the
sample is the period's mean, centred 250 µs before the packet's time.

Errors (ICM-42688-P datasheet figures, as ``sim/airframes/*.toml``): white noise per 2 kHz sample
``σ = density · √2000 Hz`` (the mean of four 8 kHz samples of ``density · √8000 Hz`` each), a
constant bias per axis, and the full-scale ranges (±2000 °/s, ±16 g), beyond which the reading
saturates. No quantisation, no vibration.
"""

import math

import numpy as np

from frames import C_FRD_FLU, flu_from_frd

#: Gyro white-noise density, rad/s/√Hz (ICM-42688-P: 2.8 mdps/√Hz).
GYRO_NOISE_DENSITY_RAD_S_PER_SQRT_HZ = 4.9e-5
#: Accelerometer white-noise density, m/s²/√Hz (ICM-42688-P: 70 µg/√Hz).
ACCEL_NOISE_DENSITY_MPS2_PER_SQRT_HZ = 6.9e-4
#: Gyro full scale, rad/s (±2000 °/s).
GYRO_RANGE_RAD_S = math.radians(2000.0)
#: Accelerometer full scale, m/s² (±16 g).
ACCEL_RANGE_MPS2 = 16.0 * 9.80665
#: The control rate the samples are averaged to, Hz (one sensor packet per 0.5 ms).
SAMPLE_RATE_HZ = 2000.0
#: RotorPy's gravity in its world frame (ENU, z up), m/s².
GRAVITY_ENU_MPS2 = np.array([0.0, 0.0, -9.81])


class ImuMount:
    """One IMU on one airframe."""

    def __init__(self, offset_frd_m, rotation_imu_frd, rng, gyro_bias_rad_s, accel_bias_mps2):
        self.offset_flu_m = flu_from_frd(offset_frd_m)
        self.rotation_imu_frd = np.asarray(rotation_imu_frd, dtype=float)
        #: FLU body axes -> IMU axes.
        self.rotation_imu_flu = self.rotation_imu_frd @ C_FRD_FLU
        self.rng = rng
        self.gyro_bias_rad_s = np.asarray(gyro_bias_rad_s, dtype=float)
        self.accel_bias_mps2 = np.asarray(accel_bias_mps2, dtype=float)
        self.gyro_sigma_rad_s = GYRO_NOISE_DENSITY_RAD_S_PER_SQRT_HZ * math.sqrt(SAMPLE_RATE_HZ)
        self.accel_sigma_mps2 = ACCEL_NOISE_DENSITY_MPS2_PER_SQRT_HZ * math.sqrt(SAMPLE_RATE_HZ)

    def specific_force_flu(self, rot_enu_flu, accel_enu_mps2, rate_flu, rate_dot_flu):
        """The true specific force at the IMU's point, body FLU axes, m/s² (no errors)."""
        r = self.offset_flu_m
        f = rot_enu_flu.T @ (accel_enu_mps2 - GRAVITY_ENU_MPS2)
        return f + _cross(rate_dot_flu, r) + _cross(rate_flu, _cross(rate_flu, r))

    def sample(self, mean_rate_flu, mean_specific_force_flu):
        """One 2 kHz sample ``(gyro rad/s, accel m/s²)`` in IMU axes from the period's means
        (body FLU), with noise, bias and saturation."""
        gyro = self.rotation_imu_flu @ mean_rate_flu + self.gyro_bias_rad_s
        accel = self.rotation_imu_flu @ mean_specific_force_flu + self.accel_bias_mps2
        gyro = gyro + self.rng.normal(0.0, self.gyro_sigma_rad_s, 3)
        accel = accel + self.rng.normal(0.0, self.accel_sigma_mps2, 3)
        gyro = np.clip(gyro, -GYRO_RANGE_RAD_S, GYRO_RANGE_RAD_S)
        accel = np.clip(accel, -ACCEL_RANGE_MPS2, ACCEL_RANGE_MPS2)
        return gyro, accel

    def offset_imu_axes_m(self):
        """The offset ``r`` in IMU axes, m (what the bridge's ``--imu-offset-mm`` takes)."""
        return self.rotation_imu_flu @ self.offset_flu_m


def _cross(a, b):
    """``a × b`` of two 3-vectors (``np.cross`` costs several times more on 3-vectors)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )
