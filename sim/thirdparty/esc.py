"""Our ESC model in front of RotorPy's rotors: normalised command δ -> rotor speed command.

The bridge's motor packet carries δ ∈ [0, 1] per motor ("0 = idle when armed"). RotorPy's
``Multirotor`` (control abstraction ``cmd_motor_speeds``) takes a commanded rotor speed per
rotor and lags the true speed behind it with its own first-order motor model,
``dω/dt = (ω_cmd − ω) / tau_m`` (``tau_m`` from the airframe's parameter set), clipped to
``[rotor_speed_min, rotor_speed_max]``. So the ESC here is only the static curve; the lag is
RotorPy's.

The curve is that of a voltage-mode ESC driving a DC motor with a propeller load (not the curve of
``sim``'s motors, ``κδ + (1 − κ)√δ``):

- the ESC applies the duty ``d = d_idle + (1 − d_idle) δ`` (an armed ESC never goes below its
  idle duty, as a DShot ESC's idle throttle);
- in steady state the duty balances back-EMF and the winding's resistive drop, and the current
  goes with the propeller's load torque ``∝ ω²``:  ``d ∝ k_e ω + R k_q ω²``. With
  ``x = ω / ω_full`` (``ω_full`` the speed at full duty) and ``β`` the resistive drop over the
  back-EMF at full speed, ``d = (x + β x²) / (1 + β)``, so

      x(d) = (√(1 + 4 β (1 + β) d) − 1) / (2 β)      (x = d for β -> 0)

  β ≈ 1 is a typical small brushless motor at full throttle (the resistive drop about equal to
  the back-EMF); the curve then lies between linear and square-root.

Arming: the packet has no arm flag, so the ESC does what a DShot ESC does with "motor stop"
frames: it stays stopped (ω_cmd = 0) until the first command above zero, and from then on idles at
δ = 0. The firmware sends exactly zero while it waits for a throw and in the release delay
(nothing spins before a throw), so the motors are still until the excitation starts.
"""

import math

#: Idle duty of an armed ESC, fraction of full duty (Betaflight's default idle is 5.5 %).
DEFAULT_IDLE_DUTY = 0.05
#: Winding resistive drop over back-EMF at full speed, dimensionless (a small brushless motor).
DEFAULT_BETA = 1.0


def steady_speed_fraction(duty, beta):
    """Steady rotor speed over the full-duty speed, ``x(d)`` of the module doc (0..1)."""
    d = min(max(duty, 0.0), 1.0)
    if beta <= 1e-9:
        return d
    return (math.sqrt(1.0 + 4.0 * beta * (1.0 + beta) * d) - 1.0) / (2.0 * beta)


class Esc:
    """The ESCs of one airframe: δ per bridge motor -> RotorPy rotor speed command, rad/s."""

    def __init__(self, full_speed_rad_s, idle_duty=DEFAULT_IDLE_DUTY, beta=DEFAULT_BETA):
        if not full_speed_rad_s > 0.0:
            raise ValueError("the full-duty speed must be positive")
        if not 0.0 <= idle_duty < 1.0:
            raise ValueError("the idle duty must be in [0, 1)")
        self.full_speed_rad_s = float(full_speed_rad_s)
        self.idle_duty = float(idle_duty)
        self.beta = float(beta)
        self.armed = False

    def speed_command_rad_s(self, delta):
        """The rotor speed command for one command ``delta`` (NaN or out of range: clamped/0)."""
        if not math.isfinite(delta):
            delta = 0.0
        delta = min(max(delta, 0.0), 1.0)
        duty = self.idle_duty + (1.0 - self.idle_duty) * delta
        return self.full_speed_rad_s * steady_speed_fraction(duty, self.beta)

    def commands_rad_s(self, deltas):
        """Speed commands for all motors; stopped (0) until the first command above zero."""
        if not self.armed and any(math.isfinite(d) and d > 0.0 for d in deltas):
            self.armed = True
        if not self.armed:
            return [0.0] * len(deltas)
        return [self.speed_command_rad_s(d) for d in deltas]
