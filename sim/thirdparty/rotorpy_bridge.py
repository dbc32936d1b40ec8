#!/usr/bin/env python3
"""Fly our firmware in RotorPy: a bridge client for a multirotor simulator we did not write.

RotorPy (``pip install rotorpy``, pinned in ``requirements.txt``) supplies the rigid body and
the rotor model (thrust and yaw torque ∝ ω², rotor drag, induced inflow, translational lift,
parasitic drag, first-order rotor lag) and its published airframe parameter sets. Around it
this client supplies, in its own code: the hand that holds and throws (``hand.py``), the IMU
mount (``imu_mount.py``), the ESCs (``esc.py``), motion capture and the frame conversions
(``frames.py``, ``flight.py``), and the bridge's packets (``bridge_packets.py``). The firmware
runs behind ``cargo run -p sim --release --bin scenario -- bridge --throw-to-fly``
(docs/sim-bridge.md); ``cargo xtask thirdparty`` builds and starts it and runs this client per
airframe.

    rotorpy_bridge.py list                       # airframes (JSON): name, motors, IMU offset
    rotorpy_bridge.py fly --airframe hummingbird --bridge 127.0.0.1:9003 [--taper-ms 15] ...

Outdoors: ``--gnss`` sends a simulated u-blox receiver's solutions instead of motion capture's poses
(``gnss.py``; run the bridge with ``--gnss-latency-ms`` equal to ``--gnss-latency-ms`` here), and
``--wind-ned-mps N,E,D`` blows a steady wind through RotorPy's drag model.

``fly`` prints one JSON summary line on stdout and exits 0 when the craft recovered to a hover and
held within 0.3 m (1 m with ``--gnss``), 1 when it did not, 2 on bad arguments, 3 when the bridge
did not answer.
"""

import argparse
import json
import math
import sys

import numpy as np

from airframes import by_name, library
from flight import BridgeTimeout, fly
from gnss import GnssReceiver
from hand import HandConfig


def _vector(text):
    parts = [float(p) for p in text.split(",")]
    if len(parts) != 3 or not all(math.isfinite(p) for p in parts):
        raise argparse.ArgumentTypeError("three finite numbers, comma-separated")
    return tuple(parts)


def _address(text):
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError("HOST:PORT, e.g. 127.0.0.1:9003")
    return host, int(port)


def _parser():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the airframes, as JSON")
    f = sub.add_parser("fly", help="one throw-and-fly through the bridge")
    f.add_argument("--airframe", required=True, help="an airframe name (see `list`)")
    f.add_argument("--bridge", type=_address, default=("127.0.0.1", 9003),
                   help="the bridge's UDP address (default 127.0.0.1:9003)")
    f.add_argument("--taper-ms", type=float, default=0.0,
                   help="taper of the hand's push, ms, 0-50 (0: one-step release)")
    f.add_argument("--taper-shape", choices=("cosine", "linear"), default="cosine")
    f.add_argument("--push-s", type=float, default=0.15, help="push duration, s, 0.1-0.3")
    f.add_argument("--release-up-mps", type=float, default=3.5,
                   help="upward speed at release, m/s")
    f.add_argument("--windup-mps", type=float, default=1.0,
                   help="downward speed of the wind-up before the push, m/s (0: none)")
    f.add_argument("--spin-dps", type=float, default=None,
                   help="body rate at release, °/s (default: the airframe's)")
    f.add_argument("--spin-axis", type=_vector, default=None,
                   help="spin axis, body FRD, x,y,z (default: the airframe's)")
    f.add_argument("--hold-s", type=float, default=2.5, help="held still before the throw, s")
    f.add_argument("--flight-s", type=float, default=12.0, help="flown after the release, s")
    f.add_argument("--hold-window-s", type=float, default=5.0,
                   help="the last seconds over which the hold error is measured")
    f.add_argument("--start-height-m", type=float, default=1.5, help="held this high, m")
    f.add_argument("--seed", type=int, default=1, help="noise seed")
    f.add_argument("--trace", action="store_true", help="the flight every 0.1 s on stderr")
    f.add_argument("--no-speed-telemetry", action="store_true",
                   help="ESCs without bidirectional DShot: send NaN for every rotor speed (run "
                        "the bridge with --no-speed-telemetry)")
    f.add_argument("--gnss", action="store_true",
                   help="a GNSS receiver's solutions instead of motion capture's poses")
    f.add_argument("--gnss-noise-m", type=float, default=0.3,
                   help="its position error per horizontal axis, m (1.5x vertically), wandering "
                        "over --gnss-correlation-s (default 0.3)")
    f.add_argument("--gnss-correlation-s", type=float, default=20.0,
                   help="how long its position error takes to change, s (default 20)")
    f.add_argument("--gnss-velocity-noise-mps", type=float, default=0.05,
                   help="its velocity noise per axis, m/s (default 0.05)")
    f.add_argument("--gnss-rate-hz", type=float, default=10.0, help="solutions a second (10)")
    f.add_argument("--gnss-latency-ms", type=float, default=100.0,
                   help="how late each solution arrives, ms, 0-200 (default 100: tell the "
                        "bridge the same with its --gnss-latency-ms)")
    f.add_argument("--wind-ned-mps", type=_vector, default=(0.0, 0.0, 0.0),
                   help="a steady wind, m/s, north,east,down (default 0,0,0)")
    return parser


def main(argv=None):
    args = _parser().parse_args(argv)
    if args.command == "list":
        rows = []
        for a in library():
            rows.append({
                "name": a.name,
                "description": a.description,
                "motors": a.params["num_rotors"],
                "mass_kg": a.params["mass"],
                "motor_tau_s": a.params["tau_m"],
                "thrust_to_weight": round(a.hover_thrust_to_weight(), 3),
                "imu_offset_mm": [round(1000.0 * c, 4) for c in a.imu_offset_imu_axes_m()],
            })
        print(json.dumps(rows, ensure_ascii=False))
        return 0

    try:
        airframe = by_name(args.airframe)
        if not (math.isfinite(args.flight_s) and 2.0 <= args.flight_s <= 120.0):
            raise ValueError("--flight-s must be 2 to 120 s")
        window_s = args.hold_window_s
        if not (math.isfinite(window_s) and 1.0 <= window_s <= args.flight_s - 1.0):
            raise ValueError("--hold-window-s must be at least 1 s and 1 s shorter than the flight")
        if not (math.isfinite(args.start_height_m) and 0.5 <= args.start_height_m <= 100.0):
            raise ValueError("--start-height-m must be 0.5 to 100 m")
        if not 0.0 <= args.taper_ms <= 50.0:
            raise ValueError("--taper-ms must be 0 to 50")
        spin_dps = args.spin_dps
        hand = HandConfig(
            hold_s=args.hold_s,
            windup_mps=args.windup_mps,
            push_s=args.push_s,
            taper_s=args.taper_ms / 1000.0,
            taper_shape=args.taper_shape,
            release_up_mps=args.release_up_mps,
            spin_rate_rad_s=(math.radians(spin_dps) if spin_dps is not None
                             else airframe.spin_rate_rad_s),
            spin_axis_frd=args.spin_axis or airframe.spin_axis_frd,
        )
        hand.validate()
        gnss = None
        if args.gnss:
            gnss = {
                "noise_m": args.gnss_noise_m,
                "rate_hz": args.gnss_rate_hz,
                "latency_s": args.gnss_latency_ms / 1000.0,
                "velocity_noise_mps": args.gnss_velocity_noise_mps,
                "correlation_s": args.gnss_correlation_s,
            }
            GnssReceiver(np.random.default_rng(0), **gnss)  # its arguments checked now
        if not all(abs(c) <= 20.0 for c in args.wind_ned_mps):
            raise ValueError("--wind-ned-mps must be within ±20 m/s on each axis")
    except (KeyError, ValueError) as error:
        print(f"rotorpy_bridge: {error}", file=sys.stderr)
        return 2

    trace = (lambda line: print(line, file=sys.stderr, flush=True)) if args.trace else None
    try:
        report = fly(airframe, hand, args.bridge, flight_s=args.flight_s,
                     hold_window_s=args.hold_window_s, start_height_m=args.start_height_m,
                     seed=args.seed, trace=trace,
                     speed_telemetry=not args.no_speed_telemetry, gnss=gnss,
                     wind_ned_mps=args.wind_ned_mps)
    except BridgeTimeout as error:
        print(f"rotorpy_bridge: {error}", file=sys.stderr)
        return 3
    print(json.dumps(report, ensure_ascii=False), flush=True)
    print(
        f"{airframe.name}, taper {report['taper_ms']} ms ({report['taper_shape']}): "
        f"{report['verdict']}; release → hover {report['release_to_hover_s']} s, hold error "
        f"{report['hold_error_m']} m (bound {report['hold_bound_m']} m), lowest {report['min_height_m']} m, "
        f"{report['wall_s']} s wall",
        file=sys.stderr,
    )
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
