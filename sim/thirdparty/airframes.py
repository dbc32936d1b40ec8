"""The airframes flown in RotorPy: its published parameter sets, one of them modified, with our
IMU mount, ESC full-duty speed, motor numbering and throw spin for each.

RotorPy 3.0.0's ``Multirotor`` packs its state with room for exactly four rotors
(``_pack_state``), so every airframe here is a quadrotor; the variety is in size (44 g to 1 kg),
motor time constant (5 to 72 ms), thrust-to-weight ratio (2 to 10), geometry (symmetric X,
asymmetric with the CoG off the rotors' centre, the PX4 preset's ordering), spin directions and
the IMU's pose. Our firmware is told none of this: it learns the motors and their positions in
flight, and the order of the bridge's motors is deliberately not RotorPy's.

Each ``motor_order[i]`` is the RotorPy rotor driven by bridge motor ``i``.
"""

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from frames import rotation_about
from rotorpy.vehicles.crazyflie_params import quad_params as crazyflie_params
from rotorpy.vehicles.crazyfliebrushless_params import quad_params as crazyflie_brushless_params
from rotorpy.vehicles.hummingbird_params import quad_params as hummingbird_params
from rotorpy.vehicles.px4_sihsim_quadx_params import quad_params as px4_sih_params


@dataclass
class Airframe:
    """One airframe: RotorPy's parameters plus what we put around them."""

    name: str
    description: str
    #: RotorPy ``quad_params`` (mass, inertia, rotors, aerodynamics, motor lag ``tau_m``).
    params: dict
    #: IMU position relative to the CoG, body FRD, m.
    imu_offset_frd_m: tuple
    #: Rotation from body FRD axes to IMU axes.
    imu_rotation_frd: np.ndarray
    #: Bridge motor i drives RotorPy rotor ``motor_order[i]``.
    motor_order: tuple
    #: ESC speed at full duty, rad/s (at most RotorPy's ``rotor_speed_max``, which clips).
    esc_full_speed_rad_s: float
    #: Throw spin: rate, rad/s, and axis, body FRD.
    spin_rate_rad_s: float = math.radians(300.0)
    spin_axis_frd: tuple = (1.0, 1.0, 0.3)
    #: Heading while held, rad.
    start_heading_rad: float = math.radians(30.0)
    #: Constant IMU biases (gyro rad/s, accelerometer m/s², IMU axes).
    gyro_bias_rad_s: tuple = (0.002, -0.003, 0.001)
    accel_bias_mps2: tuple = (0.05, -0.04, 0.08)
    extra: dict = field(default_factory=dict)

    def hover_thrust_to_weight(self):
        """Thrust at the ESC's full duty over the weight (all rotors)."""
        p = self.params
        thrust_n = p["num_rotors"] * p["k_eta"] * self.esc_full_speed_rad_s**2
        return thrust_n / (p["mass"] * 9.81)

    def imu_offset_imu_axes_m(self):
        """The IMU offset in IMU axes, m (the bridge's ``--imu-offset-mm`` for a calibrated
        board)."""
        return self.imu_rotation_frd @ np.asarray(self.imu_offset_frd_m, dtype=float)


def _asymmetric_hummingbird():
    """The Hummingbird with its arms rebuilt: shorter front arms at a wider angle, longer rear
    arms, the CoG 25 mm ahead of the rotors' centre and the rotor plane 15 mm above it, every
    spin direction reversed, 10 % heavier and with products of inertia."""
    p = copy.deepcopy(hummingbird_params)
    p["mass"] = 0.55
    p["Ixx"], p["Iyy"], p["Izz"] = 4.1e-3, 3.4e-3, 7.2e-3
    p["Ixy"], p["Ixz"], p["Iyz"] = 1.5e-4, -8.0e-5, 5.0e-5
    # FLU, relative to the CoG: front arms 0.13 m at ±50°, rear arms 0.20 m at ±140°, then the
    # whole rotor set moved 25 mm back (the CoG is ahead of the rotors' centre) and 15 mm up.
    shift = np.array([-0.025, 0.0, 0.015])
    arm = lambda length, deg: length * np.array(  # noqa: E731
        [math.cos(math.radians(deg)), math.sin(math.radians(deg)), 0.0]
    )
    p["rotor_pos"] = {
        "r1": arm(0.13, 50.0) + shift,
        "r2": arm(0.13, -50.0) + shift,
        "r3": arm(0.20, -140.0) + shift,
        "r4": arm(0.20, 140.0) + shift,
    }
    p["rotor_directions"] = -np.asarray(hummingbird_params["rotor_directions"])
    return p


def library():
    """Every airframe, in the order ``--airframes N`` takes them: first the two with fast motors
    (5 ms), which recover from the default throw (3.5 m/s up from 1.5 m) above the ground, then
    the slower ones (50–72 ms), which need 2.3–13 m below the release point to recover."""
    return [
        Airframe(
            name="hummingbird",
            description="RotorPy's AscTec Hummingbird as shipped: 0.5 kg, 0.17 m arms, X, "
            "motor lag 5 ms; IMU upside down and turned 90°, 24 mm from the CoG",
            params=copy.deepcopy(hummingbird_params),
            imu_offset_frd_m=(0.012, -0.003, -0.020),
            imu_rotation_frd=rotation_about((0, 0, 1), math.radians(90.0))
            @ rotation_about((1, 0, 0), math.pi),
            motor_order=(2, 0, 3, 1),
            esc_full_speed_rad_s=hummingbird_params["rotor_speed_max"],
            spin_rate_rad_s=math.radians(300.0),
            spin_axis_frd=(1.0, 1.0, 0.3),
        ),
        Airframe(
            name="hummingbird-asymmetric",
            description="the Hummingbird rebuilt: arms 0.13/0.20 m at ±50°/±140°, CoG 25 mm "
            "ahead of the rotors, spins reversed, 0.55 kg with products of inertia; IMU "
            "rotated 120° about (1,1,1), 18 mm from the CoG",
            params=_asymmetric_hummingbird(),
            imu_offset_frd_m=(-0.010, 0.013, 0.008),
            imu_rotation_frd=rotation_about((1, 1, 1), math.radians(120.0)),
            motor_order=(1, 3, 2, 0),
            esc_full_speed_rad_s=hummingbird_params["rotor_speed_max"],
            spin_rate_rad_s=math.radians(350.0),
            spin_axis_frd=(-0.4, 1.0, 0.6),
            start_heading_rad=math.radians(135.0),
        ),
        Airframe(
            name="crazyflie-brushless",
            description="RotorPy's Crazyflie Brushless as shipped: 44 g, 43 mm arms, X, motor "
            "lag 50 ms; IMU tilted 25°, 10 mm from the CoG",
            params=copy.deepcopy(crazyflie_brushless_params),
            imu_offset_frd_m=(0.005, -0.003, -0.008),
            imu_rotation_frd=rotation_about((1.0, -2.0, 0.5), math.radians(25.0)),
            motor_order=(3, 1, 0, 2),
            esc_full_speed_rad_s=crazyflie_brushless_params["rotor_speed_max"],
            spin_rate_rad_s=math.radians(400.0),
            spin_axis_frd=(0.2, -1.0, 0.5),
            start_heading_rad=math.radians(-70.0),
        ),
        Airframe(
            name="px4-sih-quadx",
            description="RotorPy's PX4 SIH quad-X preset: 1 kg, 0.24 m arms, motor lag 50 ms, "
            "thrust-to-weight 2.0; IMU level, 15 mm from the CoG",
            params=copy.deepcopy(px4_sih_params),
            imu_offset_frd_m=(0.0, 0.010, -0.011),
            imu_rotation_frd=np.eye(3),
            motor_order=(0, 1, 2, 3),
            esc_full_speed_rad_s=px4_sih_params["rotor_speed_max"],
            spin_rate_rad_s=math.radians(250.0),
            spin_axis_frd=(0.0, 1.0, 0.2),
            start_heading_rad=0.0,
        ),
        Airframe(
            name="crazyflie",
            description="RotorPy's Crazyflie 2.0 as shipped: 30 g, 43 mm arms, motor lag 72 ms, "
            "thrust-to-weight 2.0; IMU level at the CoG's height, 4 mm off",
            params=copy.deepcopy(crazyflie_params),
            imu_offset_frd_m=(0.003, 0.002, -0.002),
            imu_rotation_frd=rotation_about((0, 0, 1), math.radians(-90.0)),
            motor_order=(0, 2, 1, 3),
            esc_full_speed_rad_s=crazyflie_params["rotor_speed_max"],
            spin_rate_rad_s=math.radians(250.0),
            spin_axis_frd=(1.0, 0.0, 0.3),
        ),
    ]


def by_name(name):
    """The airframe called ``name``; ``KeyError`` listing the names otherwise."""
    frames = {a.name: a for a in library()}
    if name not in frames:
        raise KeyError(f"no airframe {name!r}; known: {', '.join(frames)}")
    return frames[name]
