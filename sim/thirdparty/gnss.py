"""A GNSS receiver for the RotorPy client: what a u-blox M8–M10 would report of the craft,
written from the bridge's spec (docs/sim-bridge.md, "GNSS solutions").

Assumed of a receiver (as ``sim::gnss``, our own simulator's, draws them):

- a solution every ``1 / rate_hz`` s (5–10 Hz), describing the craft at its epoch and arriving
  ``latency_s`` later (50–150 ms: the receiver's computation and its UART);
- a position error that wanders: per axis a first-order Gauss–Markov process of standard deviation
  ``noise_m`` horizontally and 1.5 times that vertically, correlated over ``correlation_s``
  (multipath and the atmosphere change over seconds, not from one solution to the next);
- a Doppler velocity with white noise of ``velocity_noise_mps`` per axis;
- accuracies as u-blox states them: ``hAcc`` the horizontal RMS (√2 σ), ``vAcc`` the vertical σ,
  ``sAcc`` the 3D velocity's RMS (√3 σ);
- the antenna at the centre of gravity.

Positions go out as WGS-84 latitude, longitude and ellipsoidal height about a fixed origin, with
the ellipsoid's meridian and prime-vertical radii (the firmware's flat earth about its first fix
agrees to 1 cm at 10 km).
"""

import math
from collections import deque

import numpy as np

from bridge_packets import GnssSolution

#: WGS-84 semi-major axis, m, and first eccentricity squared.
WGS84_A_M = 6378137.0
WGS84_E2 = 6.69437999014e-3
#: Where the simulated field is: Zürich, 47.4° N, 8.5° E, 500 m above the ellipsoid.
ORIGIN_LAT_DEG, ORIGIN_LON_DEG, ORIGIN_HEIGHT_M = 47.4, 8.5, 500.0
#: Vertical error over horizontal, per axis (u-blox receivers: 1.5–2.5).
VERTICAL_NOISE_RATIO = 1.5
#: The week's millisecond at the simulation's start (any clock will do; each value is new).
START_TIME_OF_WEEK_MS = 302_400_000


def metres_per_degree(lat_deg, height_m):
    """``(north, east)``: metres per degree of latitude and of longitude at ``lat_deg``."""
    phi = math.radians(lat_deg)
    w = math.sqrt(1.0 - WGS84_E2 * math.sin(phi) ** 2)
    meridian_m = WGS84_A_M * (1.0 - WGS84_E2) / w**3 + height_m
    prime_vertical_m = WGS84_A_M / w + height_m
    per_deg = math.pi / 180.0
    return meridian_m * per_deg, prime_vertical_m * math.cos(phi) * per_deg


class GnssReceiver:
    """Solutions of a simulated receiver; :meth:`step` is called once per control step."""

    def __init__(self, rng, noise_m=0.3, rate_hz=10.0, latency_s=0.1, velocity_noise_mps=0.05,
                 correlation_s=20.0):
        if not (math.isfinite(noise_m) and 0.0 <= noise_m <= 10.0):
            raise ValueError("GNSS noise must be 0 to 10 m")
        if not (math.isfinite(rate_hz) and 1.0 <= rate_hz <= 25.0):
            raise ValueError("GNSS rate must be 1 to 25 Hz")
        if not (math.isfinite(latency_s) and 0.0 <= latency_s <= 0.2):
            raise ValueError("GNSS latency must be 0 to 200 ms")
        if not (math.isfinite(velocity_noise_mps) and 0.0 <= velocity_noise_mps <= 2.0):
            raise ValueError("GNSS velocity noise must be 0 to 2 m/s")
        if not (math.isfinite(correlation_s) and correlation_s > 0.0):
            raise ValueError("GNSS error correlation must be positive")
        self.rng = rng
        self.noise_m = noise_m
        self.period_s = 1.0 / rate_hz
        self.latency_s = latency_s
        self.velocity_noise_mps = velocity_noise_mps
        self.correlation_s = correlation_s
        self.sigma_ned_m = noise_m * np.array([1.0, 1.0, VERTICAL_NOISE_RATIO])
        self.error_ned_m = self.rng.normal(0.0, 1.0, 3) * self.sigma_ned_m
        self.next_epoch = 0
        self.pending = deque()
        self.north_per_deg, self.east_per_deg = metres_per_degree(ORIGIN_LAT_DEG, ORIGIN_HEIGHT_M)

    def _advance_error(self, dt_s):
        """The wandering error, carried over ``dt_s`` (exact discretisation of the process)."""
        a = math.exp(-dt_s / self.correlation_s)
        kick = self.rng.normal(0.0, 1.0, 3) * self.sigma_ned_m * math.sqrt(1.0 - a * a)
        self.error_ned_m = a * self.error_ned_m + kick

    def step(self, t_s, position_ned_m, velocity_ned_mps):
        """The solution the receiver delivers at ``t_s`` (``None`` if none arrives then), given the
        craft's true position and velocity at ``t_s``."""
        if t_s + 1e-9 >= self.next_epoch * self.period_s:
            self._advance_error(self.period_s)
            measured = np.asarray(position_ned_m, dtype=float) + self.error_ned_m
            velocity = (np.asarray(velocity_ned_mps, dtype=float)
                        + self.rng.normal(0.0, self.velocity_noise_mps, 3))
            epoch_ms = START_TIME_OF_WEEK_MS + int(round(1000.0 * self.next_epoch * self.period_s))
            self.pending.append((t_s + self.latency_s, self._solution(epoch_ms, measured, velocity)))
            self.next_epoch += 1
        if self.pending and t_s + 1e-9 >= self.pending[0][0]:
            return self.pending.popleft()[1]
        return None

    def _solution(self, time_of_week_ms, position_ned_m, velocity_ned_mps):
        north, east, down = position_ned_m
        floor = 0.001  # the firmware counts accuracies below 1 mm as 1 mm
        return GnssSolution(
            time_of_week_ms=time_of_week_ms,
            latitude_deg=ORIGIN_LAT_DEG + north / self.north_per_deg,
            longitude_deg=ORIGIN_LON_DEG + east / self.east_per_deg,
            height_m=ORIGIN_HEIGHT_M - down,
            velocity_ned_mps=velocity_ned_mps,
            h_acc_m=max(floor, math.sqrt(2.0) * self.noise_m),
            v_acc_m=max(floor, VERTICAL_NOISE_RATIO * self.noise_m),
            s_acc_mps=max(floor, math.sqrt(3.0) * self.velocity_noise_mps),
        )
