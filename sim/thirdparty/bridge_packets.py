"""The lockstep bridge's two packets (docs/sim-bridge.md, "Byte layouts"), written from the spec.

Little-endian, no padding. The sensor packet is version 2 throughout (the pose field is what our
motion capture sends, the GNSS solution what a u-blox receiver would); without either its flags
are 0 and it has no trailer.
"""

import math
import struct

SENSOR_MAGIC = b"FCSN"
MOTOR_MAGIC = b"FCMO"
#: Sensor-packet flag, version 2: a 16-byte external pose follows the motor speeds.
FLAG_POSE = 0x0001
#: Sensor-packet flag, version 2: a 52-byte GNSS solution follows (after the pose, if any).
FLAG_GNSS = 0x0002
#: Motor counts the bridge accepts.
MIN_MOTORS, MAX_MOTORS = 1, 8

_HEADER = struct.Struct("<4sBBHQ")  # magic, version, motor count, flags, sequence
_SENSOR_BODY = struct.Struct("<d6f")  # time (s), gyro xyz (rad/s), specific force xyz (m/s^2)
_POSE = struct.Struct("<4f")  # north, east, down (m), heading (rad)
# time of week (ms), fix type, flags (bit 0 gnssFixOK), satellites, reserved; latitude,
# longitude (deg); height (m); velocity north, east, down (m/s); hAcc, vAcc (m); sAcc (m/s)
_GNSS = struct.Struct("<IBBBBddf3f3f")
#: NAV-PVT fixType of a 3D fix, and the gnssFixOK flag bit.
FIX_3D = 3
GNSS_FIX_OK = 0x01


class GnssSolution:
    """One receiver solution in the receiver's own terms (docs/sim-bridge.md, "GNSS solutions")."""

    def __init__(self, time_of_week_ms, latitude_deg, longitude_deg, height_m, velocity_ned_mps,
                 h_acc_m, v_acc_m, s_acc_mps, fix_type=FIX_3D, fix_ok=True, satellites=16):
        self.time_of_week_ms = int(time_of_week_ms)
        self.latitude_deg = float(latitude_deg)
        self.longitude_deg = float(longitude_deg)
        self.height_m = float(height_m)
        self.velocity_ned_mps = tuple(float(c) for c in velocity_ned_mps)
        self.h_acc_m, self.v_acc_m, self.s_acc_mps = float(h_acc_m), float(v_acc_m), float(s_acc_mps)
        self.fix_type, self.fix_ok, self.satellites = int(fix_type), bool(fix_ok), int(satellites)

    def encode(self):
        """The 52-byte block."""
        return _GNSS.pack(self.time_of_week_ms & 0xFFFFFFFF, self.fix_type,
                          GNSS_FIX_OK if self.fix_ok else 0, self.satellites, 0,
                          self.latitude_deg, self.longitude_deg, self.height_m,
                          *self.velocity_ned_mps, self.h_acc_m, self.v_acc_m, self.s_acc_mps)


class PacketError(ValueError):
    """A motor packet that is not the answer we wait for."""


def encode_sensor(sequence, time_s, gyro_rad_s, accel_mps2, speeds_rad_s, pose=None, gnss=None,
                  version=2):
    """Sensor packet bytes: ``48 + 4 m``, ``+ 16`` with a pose ``(north, east, down, heading)``,
    ``+ 52`` with a GNSS solution (a :class:`GnssSolution`).

    ``speeds_rad_s``: mechanical rotor speeds, rad/s, ``None`` or NaN for "not reported".
    """
    m = len(speeds_rad_s)
    if not MIN_MOTORS <= m <= MAX_MOTORS:
        raise ValueError(f"motor count {m} outside {MIN_MOTORS}..{MAX_MOTORS}")
    if (pose is not None or gnss is not None) and version < 2:
        raise ValueError("a pose or a GNSS solution needs version 2")
    flags = (FLAG_POSE if pose is not None else 0) | (FLAG_GNSS if gnss is not None else 0)
    speeds = [math.nan if s is None else float(s) for s in speeds_rad_s]
    out = _HEADER.pack(SENSOR_MAGIC, version, m, flags, sequence)
    out += _SENSOR_BODY.pack(float(time_s), *map(float, gyro_rad_s), *map(float, accel_mps2))
    out += struct.pack(f"<{m}f", *speeds)
    if pose is not None:
        out += _POSE.pack(*map(float, pose))
    if gnss is not None:
        out += gnss.encode()
    return out


def decode_motor(data, sequence, motor_count):
    """The commands ``δ`` (0..1, one per motor) of the motor packet answering ``sequence``.

    Raises :class:`PacketError` for a packet with the wrong magic, version, motor count or
    sequence, or too short for its motor count.
    """
    if len(data) < _HEADER.size:
        raise PacketError(f"motor packet of {len(data)} bytes, shorter than its header")
    magic, version, m, _flags, seq = _HEADER.unpack_from(data)
    if magic != MOTOR_MAGIC:
        raise PacketError(f"bad magic {magic!r}")
    if version not in (1, 2):
        raise PacketError(f"unknown version {version}")
    if m != motor_count:
        raise PacketError(f"{m} motors in the reply, {motor_count} sent")
    if seq != sequence:
        raise PacketError(f"reply to sequence {seq}, waiting for {sequence}")
    need = _HEADER.size + 4 * m
    if len(data) < need:
        raise PacketError(f"motor packet of {len(data)} bytes, needs {need}")
    return list(struct.unpack_from(f"<{m}f", data, _HEADER.size))
