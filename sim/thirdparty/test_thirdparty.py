"""Facts about the RotorPy client that could be wrong, checked without the bridge:
``python -m unittest test_thirdparty`` in sim/thirdparty (``cargo xtask thirdparty`` runs it
before flying)."""

import math
import unittest

import numpy as np

from airframes import library
from bridge_packets import GnssSolution, PacketError, decode_motor, encode_sensor
from esc import Esc, steady_speed_fraction
from flight import STEP_S, _angle_rad, _rk4_step, _wanted_thrust_axis
from frames import (
    C_FRD_FLU,
    C_NED_ENU,
    heading_rad,
    quat_xyzw_from_rotation,
    r_enu_flu,
    r_ned_frd,
    rotation_about,
    rotation_from_quat_xyzw,
)
from gnss import ORIGIN_HEIGHT_M, ORIGIN_LAT_DEG, ORIGIN_LON_DEG, GnssReceiver, metres_per_degree
from hand import FREE, GRAVITY_MPS2, Hand, HandConfig
from imu_mount import ImuMount
from rotorpy.vehicles.multirotor import Multirotor


class Packets(unittest.TestCase):
    def test_the_documented_version_2_example_byte_for_byte(self):
        # docs/sim-bridge.md: version 2, m = 2, sequence 0x0102, t = 0.5 s, gyro (1, -1, 0),
        # specific force (0, 0, -2), speeds 2.0 and not reported, pose (1.5, -2, -0.5), 0.25 rad.
        expected = bytes.fromhex(
            "46 43 53 4E 02 02 01 00  02 01 00 00 00 00 00 00"
            "00 00 00 00 00 00 E0 3F"
            "00 00 80 3F 00 00 80 BF  00 00 00 00"
            "00 00 00 00 00 00 00 00  00 00 00 C0"
            "00 00 00 40 00 00 C0 7F"
            "00 00 C0 3F 00 00 00 C0  00 00 00 BF 00 00 80 3E".replace(" ", "")
        )
        packet = encode_sensor(0x0102, 0.5, (1, -1, 0), (0, 0, -2), (2.0, None),
                               pose=(1.5, -2.0, -0.5, 0.25))
        self.assertEqual(len(packet), 72)
        self.assertEqual(packet, expected)

    def test_without_a_pose_there_is_no_trailer_and_no_flag(self):
        packet = encode_sensor(7, 0.0, (0, 0, 0), (0, 0, -9.81), (1.0, 2.0, 3.0, 4.0))
        self.assertEqual(len(packet), 48 + 16)
        self.assertEqual(packet[6:8], b"\x00\x00")

    def test_the_documented_gnss_solution_byte_for_byte(self):
        # docs/sim-bridge.md, "GNSS solutions": the pose example's packet without its pose and
        # with a 3D fix at 47.5° N, 8.5° E, 456 m, moving (0.5, -0.25, 0.125) m/s.
        expected = bytes.fromhex(
            "46 43 53 4E 02 02 02 00  02 01 00 00 00 00 00 00"
            "00 00 00 00 00 00 E0 3F"
            "00 00 80 3F 00 00 80 BF  00 00 00 00"
            "00 00 00 00 00 00 00 00  00 00 00 C0"
            "00 00 00 40 00 00 C0 7F"
            "00 42 06 12 03 01 10 00"
            "00 00 00 00 00 C0 47 40  00 00 00 00 00 00 21 40"
            "00 00 E4 43"
            "00 00 00 3F 00 00 80 BE  00 00 00 3E"
            "00 00 00 3F 00 00 80 3F  00 00 80 3E".replace(" ", "")
        )
        solution = GnssSolution(302_400_000, 47.5, 8.5, 456.0, (0.5, -0.25, 0.125),
                                h_acc_m=0.5, v_acc_m=1.0, s_acc_mps=0.25)
        packet = encode_sensor(0x0102, 0.5, (1, -1, 0), (0, 0, -2), (2.0, None), gnss=solution)
        self.assertEqual(len(packet), 108)
        self.assertEqual(packet, expected)
        with_pose = encode_sensor(0x0102, 0.5, (1, -1, 0), (0, 0, -2), (2.0, None),
                                  pose=(1.5, -2.0, -0.5, 0.25), gnss=solution)
        self.assertEqual(len(with_pose), 124)
        self.assertEqual(with_pose[6:8], b"\x03\x00")
        self.assertEqual(with_pose[-52:], expected[-52:])

    def test_a_motor_packet_is_read_and_a_wrong_one_refused(self):
        good = b"FCMO" + bytes([2, 2, 0, 0]) + (5).to_bytes(8, "little")
        good += np.array([0.25, 1.0], dtype="<f4").tobytes()
        self.assertEqual(decode_motor(good, 5, 2), [0.25, 1.0])
        with self.assertRaises(PacketError):
            decode_motor(good, 6, 2)  # another sequence
        with self.assertRaises(PacketError):
            decode_motor(good, 5, 4)  # another motor count
        with self.assertRaises(PacketError):
            decode_motor(good[:-1], 5, 2)  # cut short
        with self.assertRaises(PacketError):
            decode_motor(b"FCSN" + good[4:], 5, 2)  # a sensor packet's magic


class Frames(unittest.TestCase):
    def test_the_axis_changes_are_proper_rotations_and_their_own_inverse(self):
        for c in (C_NED_ENU, C_FRD_FLU):
            self.assertAlmostEqual(np.linalg.det(c), 1.0)
            np.testing.assert_allclose(c @ c, np.eye(3))

    def test_level_facing_north_in_both_conventions(self):
        # RotorPy ENU/FLU: body x along world y (north), body y (left) along -x (west).
        rot_enu_flu = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        np.testing.assert_allclose(r_ned_frd(rot_enu_flu), np.eye(3), atol=1e-12)
        self.assertAlmostEqual(heading_rad(r_ned_frd(rot_enu_flu)), 0.0)

    def test_heading_east_is_plus_ninety_degrees(self):
        rot = rotation_about((0, 0, 1), math.radians(90.0))  # yaw about NED down
        self.assertAlmostEqual(heading_rad(rot), math.pi / 2)
        # The same attitude in RotorPy's frames points its body x along ENU x (east).
        np.testing.assert_allclose(r_enu_flu(rot) @ [1, 0, 0], [1, 0, 0], atol=1e-12)

    def test_quaternions_round_trip(self):
        rng = np.random.default_rng(3)
        for _ in range(50):
            rot = rotation_about(rng.normal(size=3), rng.uniform(-math.pi, math.pi))
            np.testing.assert_allclose(rotation_from_quat_xyzw(quat_xyzw_from_rotation(rot)), rot,
                                       atol=1e-12)


class Receiver(unittest.TestCase):
    def test_solutions_come_at_its_rate_late_by_its_latency(self):
        receiver = GnssReceiver(np.random.default_rng(1), noise_m=0.0, rate_hz=10.0,
                                latency_s=0.1, velocity_noise_mps=0.0)
        arrivals = []
        for n in range(int(round(2.0 / STEP_S))):
            t = n * STEP_S
            # The craft flies north at 2 m/s from the origin.
            solution = receiver.step(t, (2.0 * t, 0.0, -1.0), (2.0, 0.0, 0.0))
            if solution is not None:
                arrivals.append((t, solution))
        self.assertEqual(len(arrivals), 19)  # epochs 0.0-1.8 s arrive by 1.9 s
        north_per_deg, _ = metres_per_degree(ORIGIN_LAT_DEG, ORIGIN_HEIGHT_M)
        for k, (t, solution) in enumerate(arrivals):
            self.assertAlmostEqual(t, 0.1 * k + 0.1, places=6)
            # It describes the epoch 0.1 s before it arrived, at 2 m/s.
            north_m = (solution.latitude_deg - ORIGIN_LAT_DEG) * north_per_deg
            self.assertAlmostEqual(north_m, 2.0 * 0.1 * k, places=6)
            self.assertAlmostEqual(solution.longitude_deg, ORIGIN_LON_DEG)
            self.assertAlmostEqual(solution.height_m, ORIGIN_HEIGHT_M + 1.0, places=4)
            self.assertEqual(solution.time_of_week_ms - arrivals[0][1].time_of_week_ms, 100 * k)

    def test_a_metre_of_latitude_is_the_meridians(self):
        # WGS-84 at 47.4° N, 500 m: the meridian radius M = a(1 - e²)/W³ ≈ 6,370.6 km, so one
        # degree is 111.19 km (111.13 at 45°, 111.23 at 50°); a degree of longitude is
        # N cos φ ≈ 75.49 km (78.85 at 45°, 71.70 at 50°).
        north, east = metres_per_degree(47.4, 500.0)
        self.assertAlmostEqual(north / 1000.0, 111.19, delta=0.01)
        self.assertAlmostEqual(east / 1000.0, 75.49, delta=0.01)

    def test_its_error_wanders_with_the_stated_spread_and_accuracies(self):
        noise_m = 0.3
        receiver = GnssReceiver(np.random.default_rng(7), noise_m=noise_m, rate_hz=10.0,
                                latency_s=0.0, velocity_noise_mps=0.1, correlation_s=2.0)
        errors, steps = [], []
        north_per_deg, east_per_deg = metres_per_degree(ORIGIN_LAT_DEG, ORIGIN_HEIGHT_M)
        for k in range(20_000):  # 2,000 s: 1,000 correlation times
            solution = receiver.step(0.1 * k, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
            errors.append(((solution.latitude_deg - ORIGIN_LAT_DEG) * north_per_deg,
                           (solution.longitude_deg - ORIGIN_LON_DEG) * east_per_deg))
            steps.append(solution.velocity_ned_mps)
        errors = np.array(errors)
        # σ per axis within 10 % (1,000 independent stretches), and hAcc its RMS (√2 σ).
        np.testing.assert_allclose(errors.std(axis=0), noise_m, rtol=0.1)
        self.assertAlmostEqual(solution.h_acc_m, math.sqrt(2.0) * noise_m)
        # Correlated over 2 s: errors 1 s apart correlate as exp(-1 s / 2 s) = 0.61.
        for axis in range(2):
            e = errors[:, axis]
            self.assertAlmostEqual(np.corrcoef(e[:-10], e[10:])[0, 1], math.exp(-0.5), delta=0.05)
        np.testing.assert_allclose(np.array(steps).std(axis=0), 0.1, rtol=0.1)
        self.assertAlmostEqual(solution.s_acc_mps, math.sqrt(3.0) * 0.1)

    def test_a_receiver_out_of_range_is_refused(self):
        for bad in ({"rate_hz": 0.0}, {"latency_s": 0.5}, {"noise_m": math.nan}):
            with self.assertRaises(ValueError):
                GnssReceiver(np.random.default_rng(0), **bad)


class EscCurve(unittest.TestCase):
    def test_curve_ends_idle_monotonic_and_between_linear_and_square_root(self):
        esc = Esc(1000.0, idle_duty=0.05, beta=1.0)
        self.assertAlmostEqual(esc.speed_command_rad_s(1.0), 1000.0)
        self.assertGreater(esc.speed_command_rad_s(0.0), 0.0)
        speeds = [esc.speed_command_rad_s(d) for d in np.linspace(0, 1, 101)]
        self.assertTrue(all(b > a for a, b in zip(speeds, speeds[1:])))
        for d in (0.1, 0.3, 0.7):
            self.assertGreater(steady_speed_fraction(d, 1.0), d)
            self.assertLess(steady_speed_fraction(d, 1.0), math.sqrt(d))
        # The steady state it solves: duty = (x + β x²)/(1 + β).
        x = steady_speed_fraction(0.4, 1.0)
        self.assertAlmostEqual((x + x * x) / 2.0, 0.4)

    def test_stopped_until_a_command_above_zero_then_idle_at_zero(self):
        esc = Esc(1000.0)
        self.assertEqual(esc.commands_rad_s([0.0, 0.0]), [0.0, 0.0])
        self.assertEqual(esc.commands_rad_s([math.nan, -1.0]), [0.0, 0.0])
        esc.commands_rad_s([0.0, 0.02])
        idle = esc.commands_rad_s([0.0, 0.0])
        self.assertTrue(all(w > 0.0 for w in idle))


def _free_body(airframe, w_flu):
    """A RotorPy state at rest in position, rotors stopped, turning at ``w_flu``."""
    return Multirotor._pack_state({
        "x": np.array([0.0, 0.0, 10.0]), "v": np.zeros(3),
        "q": quat_xyzw_from_rotation(rotation_about((1, 2, 3), 0.7)),
        "w": np.asarray(w_flu, dtype=float), "wind": np.zeros(3),
        "rotor_speeds": np.zeros(airframe.params["num_rotors"]),
    })


class ImuAndHand(unittest.TestCase):
    def setUp(self):
        self.airframe = library()[0]
        self.model = Multirotor(self.airframe.params, control_abstraction="cmd_motor_speeds")

    def imu(self, offset_frd_m, rotation):
        return ImuMount(offset_frd_m, rotation, np.random.default_rng(0), (0, 0, 0), (0, 0, 0))

    def test_at_rest_level_an_frd_imu_reads_minus_g_on_z(self):
        hand = Hand(HandConfig(hold_s=1.0), STEP_S)
        imu = self.imu((0.01, 0.02, -0.03), np.eye(3))
        state = _free_body(self.airframe, (0, 0, 0))
        state[6:10] = quat_xyzw_from_rotation(r_enu_flu(np.eye(3)))
        _, rate, force, _ = _rk4_step(self.model, hand, imu, state, 0.0,
                                   np.zeros(self.airframe.params["num_rotors"]))
        np.testing.assert_allclose(imu.rotation_imu_flu @ force, [0, 0, -GRAVITY_MPS2], atol=1e-9)
        np.testing.assert_allclose(rate, 0.0, atol=1e-12)

    def test_spinning_freely_the_imu_reads_the_centripetal_term_and_nothing_else(self):
        # Rotors stopped, no aerodynamics: free fall, so the IMU at r reads Ω×(Ω×r), not
        # gravity. (With `aero`, RotorPy's translational lift `k_h (v_x² + v_y²)` at each hub
        # acts even on stopped rotors: 0.08 m/s² here from the hubs' 1.7 m/s.)
        model = Multirotor(self.airframe.params, control_abstraction="cmd_motor_speeds",
                           aero=False)
        hand = Hand(HandConfig(hold_s=1.0), STEP_S)
        imu = self.imu((0.02, 0.0, 0.0), np.eye(3))
        w_flu = np.array([0.0, 0.0, 10.0])  # about body up: no Euler torque for this inertia
        state = _free_body(self.airframe, w_flu)
        self.assertEqual(hand.phase(10.0), FREE)
        _, _, force, _ = _rk4_step(model, hand, imu, state, 10.0,
                                np.zeros(self.airframe.params["num_rotors"]))
        r_flu = C_FRD_FLU @ np.array([0.02, 0.0, 0.0])
        expected = np.cross(w_flu, np.cross(w_flu, r_flu))  # -|Ω|² r: 2 m/s² inwards
        np.testing.assert_allclose(force, expected, atol=1e-9)

    def test_the_wanted_thrust_axis_leans_into_the_wind_by_the_drag_and_is_up_in_still_air(self):
        # Level, rotors at the speed that carries the weight, at rest in RotorPy's drag model.
        model = Multirotor(self.airframe.params, control_abstraction="cmd_motor_speeds",
                           aero=True)
        m = self.airframe.params["num_rotors"]
        hover = math.sqrt(self.airframe.params["mass"] * GRAVITY_MPS2
                          / (m * self.airframe.params["k_eta"]))
        hand = Hand(HandConfig(hold_s=1.0), STEP_S)
        imu = self.imu((0.0, 0.0, 0.0), np.eye(3))
        up = np.array([0.0, 0.0, 1.0])
        for wind_east_mps in (0.0, 4.0):
            state = _free_body(self.airframe, (0, 0, 0))
            state[6:10] = quat_xyzw_from_rotation(r_enu_flu(np.eye(3)))
            state[13:16] = (wind_east_mps, 0.0, 0.0)
            state[16:16 + m] = hover
            _, _, _, accel = _rk4_step(model, hand, imu, state, 10.0, np.full(m, hover))
            wanted = _wanted_thrust_axis(up, accel)
            # The wind pushes the craft east (along the air's motion): only a thrust leaning west,
            # into the wind, cancels it, by atan(drag / weight).
            lean = math.atan2(accel[0], GRAVITY_MPS2)
            self.assertAlmostEqual(_angle_rad(wanted, up), abs(lean), delta=1e-3)
            if wind_east_mps == 0.0:
                self.assertLess(_angle_rad(wanted, up), math.radians(0.01))
            else:
                self.assertGreater(accel[0], 0.1)
                self.assertLess(wanted[0], 0.0)

    def test_the_throw_releases_at_the_asked_velocity_and_rate_whatever_the_taper(self):
        for taper_s, shape in ((0.0, "cosine"), (0.015, "cosine"), (0.03, "linear")):
            config = HandConfig(hold_s=0.5, taper_s=taper_s, taper_shape=shape,
                                release_up_mps=3.5, windup_mps=1.0,
                                spin_rate_rad_s=math.radians(300.0), spin_axis_frd=(1, 1, 0.3))
            hand = Hand(config, STEP_S)
            imu = self.imu((0.0, 0.0, 0.0), np.eye(3))
            state = _free_body(self.airframe, (0, 0, 0))
            n = int(round(hand.release_s / STEP_S))
            peak_force = 0.0
            last_force = None
            for i in range(n):
                state, _, force, _ = _rk4_step(self.model, hand, imu, state, i * STEP_S,
                                            np.zeros(self.airframe.params["num_rotors"]))
                peak_force = max(peak_force, float(np.linalg.norm(force)))
                last_force = float(np.linalg.norm(force))
            np.testing.assert_allclose(state[3:6], [0, 0, 3.5], atol=1e-9)
            np.testing.assert_allclose(np.linalg.norm(state[10:13]), math.radians(300.0),
                                       rtol=1e-9)
            axis = C_FRD_FLU @ np.array([1, 1, 0.3]) / np.linalg.norm([1, 1, 0.3])
            np.testing.assert_allclose(state[10:13] / np.linalg.norm(state[10:13]), axis,
                                       atol=1e-9)
            # The push is a throw for the detector (|f| above 20 m/s², below its 45 m/s² clip);
            # with a taper the last sample before release is already near free fall.
            self.assertGreater(peak_force, 20.0)
            self.assertLess(peak_force, 45.0)
            if taper_s > 0:
                self.assertLess(last_force, 2.0)
            else:
                self.assertGreater(last_force, 20.0)

    def test_bad_hand_values_are_refused(self):
        for bad in (dict(taper_s=0.06), dict(push_s=0.05), dict(taper_shape="square"),
                    dict(release_up_mps=math.nan), dict(spin_axis_frd=(0, 0, 0))):
            with self.assertRaises(ValueError, msg=str(bad)):
                HandConfig(**bad).validate()


class Airframes(unittest.TestCase):
    def test_every_airframe_can_hover_and_numbers_its_motors_once(self):
        for a in library():
            with self.subTest(a.name):
                self.assertEqual(sorted(a.motor_order), list(range(a.params["num_rotors"])))
                self.assertGreater(a.hover_thrust_to_weight(), 1.5)
                self.assertLessEqual(a.esc_full_speed_rad_s, a.params["rotor_speed_max"])
                np.testing.assert_allclose(a.imu_rotation_frd @ a.imu_rotation_frd.T, np.eye(3),
                                           atol=1e-12)
                # Within the 30 mm the firmware's free-fall check allows for.
                self.assertLess(np.linalg.norm(a.imu_offset_frd_m), 0.03)


if __name__ == "__main__":
    unittest.main()
