//! `fit imu-offset`: see the module docs once written.
