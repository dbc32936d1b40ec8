//! The simulator: physics, sensors, motors, airframes, and the SITL server.
