"""The hand: holds the craft still, winds up, throws it spinning, and lets go.

RotorPy has no hand, so the hand is kinematic, in our own code: while it acts it *prescribes*
the CoG acceleration (world) and the body's angular acceleration, replacing what RotorPy's
``Multirotor`` derivative says for them (a firm hand supplies whatever force and torque the
difference takes, as ``sim::hand`` does in our own simulator). Rotor speeds, position and
attitude keep integrating from RotorPy's derivative, so everything the IMU and the motion
capture see is consistent with the prescribed motion.

Phases (times from the start of the flight, each a whole number of 0.5 ms steps):

1. **hold** (``hold_s``): velocity and body rate zero, the craft level at ``start_heading``. The
   board sees a rest (specific force ``g`` up, no rotation).
2. **wind-up** (``windup_s``): the hand lowers the craft before the throw, as a person does; the
   acceleration is a raised cosine, ``a_up(τ) = −(v_w / T_w)(1 − cos 2πτ/T_w)``, taking the
   velocity smoothly from 0 to ``−windup_mps`` (peak ``2 v_w / T_w``, 6.7 m/s² down by default:
   the specific force stays below 20 m/s², so the throw detector does not start yet). With it the
   push's speed change, which is what the detector integrates as "momentum", exceeds the release
   speed: ``release_up_mps + windup_mps``.
3. **push** (``push_s`` in all, the taper included): the hand's *own* specific force — its force
   on the craft per unit mass, world vertical — is ``H s(τ)`` and the angular acceleration about
   ``spin_axis`` is ``A s(τ)``, with ``s = 1`` until the taper starts and then a ramp to 0 over
   ``taper_s``: linear ``1 − u`` or cosine ``(1 + cos πu)/2`` with ``u`` from 0 to 1. The CoG
   acceleration is ``H s − g`` up. ``H`` and ``A`` are set so that at the end of the push the
   CoG moves at ``release_up_mps`` up and the body turns at ``spin_rate_rad_s``:
   ``∫s = push_s − taper_s / 2`` for both ramps. A zero taper is a one-step release (the hand's
   force drops from ``H`` to 0 between two steps); with a taper the specific force the IMU reads
   comes down smoothly to free fall, as a real hand's does.
4. **free**: RotorPy's dynamics alone.

Why the taper ramps the *hand's* force and not the CoG acceleration: the hand's contact force is
what goes to zero as the craft leaves the fingers; the CoG acceleration then ends at ``−g``, not
at zero.
"""

import math
from dataclasses import dataclass

import numpy as np

from frames import flu_from_frd

#: RotorPy's gravity (``Multirotor.g``), m/s².
GRAVITY_MPS2 = 9.81

HOLD, WINDUP, PUSH, FREE = "hold", "windup", "push", "free"


@dataclass
class HandConfig:
    """What the hand does; every time in seconds, speeds in m/s, rates in rad/s."""

    #: Held still before the wind-up, s (the board's rest).
    hold_s: float = 2.5
    #: Duration of the wind-up, s.
    windup_s: float = 0.3
    #: Downward speed the wind-up reaches, m/s (0: no wind-up).
    windup_mps: float = 1.0
    #: Duration of the push including its taper, s (0.1–0.3).
    push_s: float = 0.15
    #: Duration of the taper at the end of the push, s (0–0.05; 0 = one-step release).
    taper_s: float = 0.0
    #: Shape of the taper: "cosine" or "linear".
    taper_shape: str = "cosine"
    #: Upward CoG speed at release, m/s.
    release_up_mps: float = 3.5
    #: Body rate at release, rad/s.
    spin_rate_rad_s: float = math.radians(300.0)
    #: Spin axis, body FRD (any length).
    spin_axis_frd: tuple = (1.0, 1.0, 0.3)

    def validate(self):
        """Raises ``ValueError`` naming the first value out of its range."""
        checks = [
            ("hold_s", self.hold_s, 0.5, 30.0),
            ("windup_s", self.windup_s, 0.05, 1.0),
            ("windup_mps", self.windup_mps, 0.0, 3.0),
            ("push_s", self.push_s, 0.1, 0.3),
            ("taper_s", self.taper_s, 0.0, 0.05),
            ("release_up_mps", self.release_up_mps, 1.0, 10.0),
            ("spin_rate_rad_s", self.spin_rate_rad_s, 0.0, math.radians(1000.0)),
        ]
        for name, value, low, high in checks:
            if not (math.isfinite(value) and low <= value <= high):
                raise ValueError(f"{name} = {value} outside [{low}, {high}]")
        if self.taper_shape not in ("cosine", "linear"):
            raise ValueError(f"taper shape {self.taper_shape!r}: cosine or linear")
        if self.taper_s > 0.5 * self.push_s:
            raise ValueError("the taper may take at most half the push")
        if not np.linalg.norm(self.spin_axis_frd) > 0.0:
            raise ValueError("the spin axis must not be zero")


class Hand:
    """The hand's prescription over time, on a grid of ``step_s``."""

    def __init__(self, config, step_s):
        config.validate()
        self.config = config
        steps = lambda seconds: max(int(round(seconds / step_s)), 0)  # noqa: E731
        self.windup_start_s = steps(config.hold_s) * step_s
        self.push_start_s = self.windup_start_s + steps(config.windup_s) * step_s
        self.release_s = self.push_start_s + steps(config.push_s) * step_s
        self.push_s = self.release_s - self.push_start_s
        self.windup_s = self.push_start_s - self.windup_start_s
        self.taper_s = config.taper_s
        self.taper_start_tau_s = self.push_s - self.taper_s
        mean_shape_s = self.push_s - 0.5 * self.taper_s  # ∫ s(τ) dτ for both ramps
        speed_change_mps = config.release_up_mps + (config.windup_mps if self.windup_s > 0 else 0)
        #: The hand's specific force at full push, m/s² (world up).
        self.push_specific_force_mps2 = (
            speed_change_mps + GRAVITY_MPS2 * self.push_s
        ) / mean_shape_s
        axis = np.asarray(config.spin_axis_frd, dtype=float)
        axis_flu = flu_from_frd(axis / np.linalg.norm(axis))
        #: Angular acceleration at full push, rad/s², body FLU.
        self.push_alpha_flu = axis_flu * (config.spin_rate_rad_s / mean_shape_s)

    def phase(self, step_start_s):
        """The phase of the integration step that starts at ``step_start_s``.

        A step belongs to one phase as a whole (phase changes fall on step boundaries), so the
        integrator's stages at the step's end still see the step's phase.
        """
        eps = 1e-9
        if step_start_s < self.windup_start_s - eps:
            return HOLD
        if step_start_s < self.push_start_s - eps:
            return WINDUP
        if step_start_s < self.release_s - eps:
            return PUSH
        return FREE

    def shape(self, tau_s):
        """``s(τ)`` of the push: 1, then the taper to 0 (closed on the right)."""
        if self.taper_s <= 0.0 or tau_s <= self.taper_start_tau_s:
            return 1.0
        u = min((tau_s - self.taper_start_tau_s) / self.taper_s, 1.0)
        if self.config.taper_shape == "linear":
            return 1.0 - u
        return 0.5 * (1.0 + math.cos(math.pi * u))

    def prescribed(self, phase, t_s):
        """``(CoG acceleration world ENU m/s², angular acceleration body FLU rad/s²)`` the hand
        imposes at ``t_s`` within a step of ``phase``, or ``None`` when the hand is off."""
        if phase == HOLD:
            return _ZERO, _ZERO
        if phase == WINDUP:
            tau = t_s - self.windup_start_s
            v_w, t_w = self.config.windup_mps, self.windup_s
            up = -(v_w / t_w) * (1.0 - math.cos(2.0 * math.pi * tau / t_w))
            return np.array([0.0, 0.0, up]), _ZERO
        if phase == PUSH:
            s = self.shape(t_s - self.push_start_s)
            up = self.push_specific_force_mps2 * s - GRAVITY_MPS2
            return np.array([0.0, 0.0, up]), self.push_alpha_flu * s
        return None


_ZERO = np.zeros(3)
