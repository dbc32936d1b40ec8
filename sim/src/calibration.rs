//! IMU-offset calibration sessions on the simulator: two throw-and-catches of one airframe, held
//! still before and after each, fitted as the configurator fits them (`fit imu-offset`), with the
//! truth to compare against.
//!
//! A session is drawn as a new user would throw: apexes of 0.8–1.5 m, spins of 300–600 °/s about
//! axes at least 50° apart, a constant accelerometer bias drawn per axis from `N(0, σ²)`, the
//! airframe's own drag, the ICM-42688-P noise and quantisation at 8 kHz averaged to 2 kHz, and a
//! rest of [`REST_S`] in the hand before the throw and after the catch (the catch leaves the craft
//! in a new attitude). [`monte_carlo`] runs many sessions and summarises what a user would see:
//! how often two throws are declared enough, how often the truth lies inside the reported 95 %
//! ellipsoid, and the error.
//!
//! Each session is also thrown once more as one continuous stream, as the board sees a
//! calibration (rest, throw, catch, rest, throw, catch, rest: the rest between the throws is one
//! attitude, so three rest poses where the two logs hold four), and fed to the board's own
//! estimator ([`ImuOffsetEstimator`], `f32`). Its verdict is judged twice: at the second catch,
//! the moment the board reports the throw (`calibrate imu-offset` concluded on that verdict
//! alone until issue 28), and once the craft has rested after the catch, which is where the rest
//! poses separate an accelerometer bias from the offset along the direction equal-rate spins
//! leave open (the cross product of the two spin axes).

use imu_offset::{
    BatchFitter, Config, DragModel, Estimate, ImuOffsetEstimator, ImuSample, Model, Scalar,
    CHI2_3DOF_95,
};
use nalgebra::{Matrix3, Vector3};

use crate::airframe::Airframe;
use crate::board::{SimBoard, SimConfig};
use crate::hand::HandPhase;
use crate::rng::Rng;
use crate::scenario::{self, FlightApp, ScenarioConfig, ScenarioKind};
use crate::stats;

/// The simulator's IMU rate as the application sees it (Hz): 8 kHz averaged in fours.
pub const RATE_HZ: f32 = 2000.0;

/// Rest in the hand before each throw and after each catch (s): a user holds the craft for a
/// moment before throwing and looks at it after catching.
pub const REST_S: f64 = 0.6;

/// Airframes the sessions cycle through by default: the built-in quads (0.18–0.6 kg, the craft a
/// hand throws spinning and catches). The 1.5 kg hexacopters and the octocopter can be chosen
/// alone (`--airframe`); their drag, ten times the quads' per unit mass, limits the fit.
pub const AIRFRAMES: [&str; 3] = ["paper-quad", "quad-3in", "racer-5in"];

/// How the two spins of a session are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpinDraw {
    /// Each throw at its own rate, 300–600 °/s, about random axes at least 50° apart.
    Random,
    /// Both throws at one rate, 300–600 °/s, about random axes at least 50° apart: the seed
    /// paper's throws, where a bias and the offset are inseparable in free fall along the cross
    /// product of the axes.
    EqualRate,
    /// Both throws at one rate, 300–600 °/s, each about a body axis (roll, pitch or yaw, either
    /// sign), two different ones: as people spin a craft. A yaw spin leaves the craft level
    /// after the catch, so the rests before and after it are one attitude.
    BodyAxes,
}

/// One drawn session: the airframe (with its bias), the two spins and apexes.
#[derive(Debug, Clone)]
pub struct Session {
    /// The airframe thrown, its accelerometer bias replaced by the drawn one.
    pub airframe: Airframe,
    /// The drawn accelerometer bias (m/s², IMU axes).
    pub acc_bias_mps2: Vector3<f64>,
    /// Body rates at release (rad/s, body axes).
    pub spins_rad_s: [Vector3<f64>; 2],
    /// Apex heights above release (m).
    pub apexes_m: [f64; 2],
    /// Noise seed of the simulator.
    pub seed: u64,
}

impl Session {
    /// Session `seed` with accelerometer bias `bias_sigma_mps2` (1σ per axis), spins
    /// [`SpinDraw::Random`]. `airframe` replaces the default cycle through [`AIRFRAMES`].
    pub fn random(seed: u64, bias_sigma_mps2: f64, airframe: Option<&Airframe>) -> Self {
        Self::drawn(seed, bias_sigma_mps2, airframe, SpinDraw::Random)
    }

    /// Session `seed` with accelerometer bias `bias_sigma_mps2` (1σ per axis) and spins drawn
    /// as `spins` says. `airframe` replaces the default cycle through [`AIRFRAMES`].
    pub fn drawn(
        seed: u64,
        bias_sigma_mps2: f64,
        airframe: Option<&Airframe>,
        spins: SpinDraw,
    ) -> Self {
        let mut rng = Rng::new(seed ^ 0xCA1_1B8A7E);
        let name = AIRFRAMES[(seed % AIRFRAMES.len() as u64) as usize];
        let mut airframe = match airframe {
            Some(a) => a.clone(),
            None => Airframe::builtin(name).expect("built-in airframes parse"),
        };
        let acc_bias_mps2 =
            Vector3::new(rng.normal(), rng.normal(), rng.normal()) * bias_sigma_mps2;
        airframe.imu.accel.bias_mps2 = acc_bias_mps2.into();
        let unit =
            |rng: &mut Rng| Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
        let first = unit(&mut rng);
        // At least 50° apart (as lines: a spin about −a is the same axis).
        let second = loop {
            let b = unit(&mut rng);
            if first.dot(&b).abs() <= 50f64.to_radians().cos() {
                break b;
            }
        };
        let spins_rad_s = match spins {
            SpinDraw::Random => {
                [first, second].map(|axis| axis * rng.range(300.0, 600.0).to_radians())
            }
            SpinDraw::EqualRate => {
                let rate = rng.range(300.0, 600.0).to_radians();
                [first * rate, second * rate]
            }
            SpinDraw::BodyAxes => {
                let rate = rng.range(300.0, 600.0).to_radians();
                let a = (rng.range(0.0, 3.0) as usize).min(2);
                let b = (a + 1 + (rng.range(0.0, 2.0) as usize).min(1)) % 3;
                let sign = |rng: &mut Rng| if rng.range(0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
                let sa = sign(&mut rng);
                let sb = sign(&mut rng);
                [Vector3::ith(a, sa * rate), Vector3::ith(b, sb * rate)]
            }
        };
        let apexes_m = [rng.range(0.8, 1.5), rng.range(0.8, 1.5)];
        Self { airframe, acc_bias_mps2, spins_rad_s, apexes_m, seed }
    }

    /// Session `seed` on `airframe` exactly as it is: its IMU's errors (scale, cross-axis, its
    /// own accelerometer bias), drag and inertia; spins [`SpinDraw::Random`]. For the
    /// calibration on a random world's airframe (`sim::world`).
    pub fn on_airframe(seed: u64, airframe: &Airframe) -> Self {
        let mut session = Self::drawn(seed, 0.0, Some(airframe), SpinDraw::Random);
        session.airframe.imu.accel.bias_mps2 = airframe.imu.accel.bias_mps2;
        session.acc_bias_mps2 = airframe.imu.accel.bias_mps2.into();
        session
    }

    /// The true offset (m, IMU axes).
    pub fn truth_m(&self) -> Vector3<f64> {
        self.airframe.q_imu_body() * self.airframe.r_imu_m()
    }

    /// The IMU logs of the two throws (each: rest, throw, free fall, catch, rest).
    pub fn logs(&self) -> [Vec<ImuSample>; 2] {
        [0, 1].map(|k| {
            let mut config = ScenarioConfig::new(ScenarioKind::ThrowCatch);
            config.throw_rate_body_rad_s = self.spins_rad_s[k];
            config.throw_apex_m = self.apexes_m[k];
            config.hold_before_s = REST_S;
            config.after_catch_s = REST_S;
            config.board.seed = self.seed.wrapping_mul(2).wrapping_add(k as u64);
            let mut recorder = Recorder::default();
            scenario::run::<_, std::io::Sink>(
                &self.airframe,
                &config,
                &mut recorder,
                None,
                &mut |_, _| {},
            )
            .expect("a calibration throw runs");
            recorder.0
        })
    }

    /// The whole session as one stream, as the board sees a calibration: held still for
    /// [`REST_S`], thrown, caught, held still for twice [`REST_S`] (the rest after the first catch
    /// is the rest before the second throw), thrown, caught, held still for [`REST_S`]. Also the
    /// index of the first sample after the second catch's hand has come to hold the craft.
    pub fn stream(&self) -> (Vec<ImuSample>, usize) {
        let config =
            SimConfig { seed: self.seed.wrapping_mul(2).wrapping_add(7), ..SimConfig::default() };
        let mut board = SimBoard::new(&self.airframe, &config);
        let mut samples = Vec::new();
        let rate = f64::from(RATE_HZ);
        let hold = |board: &mut SimBoard, samples: &mut Vec<ImuSample>, seconds: f64| {
            for _ in 0..(seconds * rate).round() as usize {
                board.tick();
                let s = board.last_sample();
                samples.push(ImuSample {
                    gyro_radps: Vector3::from(s.gyro_rad_s),
                    acc_mps2: Vector3::from(s.accel_mps2),
                });
            }
        };
        let mut rest_after_last_catch = 0;
        for (k, (spin, apex)) in self.spins_rad_s.iter().zip(self.apexes_m).enumerate() {
            hold(&mut board, &mut samples, if k == 0 { REST_S } else { REST_S * 2.0 });
            let mut config = ScenarioConfig::new(ScenarioKind::ThrowCatch);
            config.throw_rate_body_rad_s = *spin;
            config.throw_apex_m = apex;
            let spec = config.throw_spec();
            board.physics_mut().throw_and_catch_at_release_height(&spec, config.catch_tau_s);
            // Until the hand holds the craft again (at most 10 s: a throw lasts about 1.5 s).
            for _ in 0..(10.0 * rate) as usize {
                hold(&mut board, &mut samples, 1.0 / rate);
                let hand = board.physics().hand();
                if hand.caught_at_s().is_some() && hand.phase() == HandPhase::Holding {
                    break;
                }
            }
            rest_after_last_catch = samples.len();
        }
        hold(&mut board, &mut samples, REST_S);
        (samples, rest_after_last_catch)
    }
}

/// The board's estimator on a session's stream ([`Session::stream`]): its estimate when the
/// second throw is accepted (at the catch) and after the whole stream (the rest after the catch
/// in progress, as the board's status shows it).
/// `drag_model` as in the fits (the board's default is [`DragModel::VerticalQuadratic`]).
pub fn onboard(
    samples: &[ImuSample],
    drag_model: DragModel,
) -> (Option<Estimate<f32>>, Option<Estimate<f32>>) {
    let config = Config { drag_model, ..Config::default() };
    let Ok(mut estimator) = ImuOffsetEstimator::new(RATE_HZ, config) else {
        return (None, None);
    };
    let mut at_second_catch = None;
    for sample in samples {
        if let Ok(Some(_)) = estimator.update(sample) {
            if estimator.segments().len() == 2 {
                at_second_catch = estimator.estimate().ok();
            }
        }
    }
    (at_second_catch, estimator.estimate().ok())
}

/// Reads every IMU sample into memory, commands nothing.
#[derive(Default)]
struct Recorder(Vec<ImuSample>);

impl FlightApp for Recorder {
    fn step<I: firmware::app::hal::Imu, M: firmware::app::hal::Motors>(
        &mut self,
        _now_us: u64,
        imu: &mut I,
        _motors: &mut M,
    ) {
        if let Some(s) = imu.read() {
            self.0.push(ImuSample {
                gyro_radps: Vector3::from(s.gyro_rad_s),
                acc_mps2: Vector3::from(s.accel_mps2),
            });
        }
    }
}

/// One fit of a session, judged against the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Judged {
    /// Declared well determined.
    pub well_determined: bool,
    /// `|r̂ − r|` (m).
    pub error_m: f64,
    /// `(r̂ − r)ᵀ Σ⁻¹ (r̂ − r) / χ²₃(0.95)`: at most 1 when the truth is inside the ellipsoid.
    pub normalised_mahalanobis: f64,
    /// Largest reported 95 % semi-axis (m).
    pub largest_semi_axis_m: f64,
    /// Rest poses used.
    pub rest_poses: u32,
    /// `|b̂ − b|` (m/s²), when the bias was fitted.
    pub bias_error_mps2: Option<f64>,
}

impl Judged {
    /// `estimate` (the host's `f64` or the board's `f32`) against the truth.
    pub fn new<T: Scalar + Into<f64>>(
        estimate: &Estimate<T>,
        truth_m: &Vector3<f64>,
        bias_mps2: &Vector3<f64>,
    ) -> Self {
        let wide = |v: &Vector3<T>| v.map(Into::into);
        let error = wide(&estimate.r_imu_m) - truth_m;
        let covariance: Matrix3<f64> = estimate.covariance_m2.map(Into::into);
        let inverse = covariance.try_inverse().unwrap_or_else(Matrix3::zeros);
        Self {
            well_determined: estimate.verdict.is_well_determined(),
            error_m: error.norm(),
            normalised_mahalanobis: error.dot(&(inverse * error)) / f64::from(CHI2_3DOF_95),
            largest_semi_axis_m: estimate.ellipsoid.semi_axes_m[0].into(),
            rest_poses: estimate.rest_poses,
            bias_error_mps2: estimate.acc_bias_mps2.map(|b| (wide(&b) - bias_mps2).norm()),
        }
    }
}

/// Fit a session's logs with `model` and `drag_model`, as `fit imu-offset [--no-drag]` does.
pub fn fit(
    logs: &[Vec<ImuSample>],
    model: Model,
    drag_model: DragModel,
) -> Result<Estimate<f64>, String> {
    fit_with(logs, Config { model, drag_model, ..Config::default() })
}

/// Fit a session's logs with `config`.
pub fn fit_with(logs: &[Vec<ImuSample>], config: Config) -> Result<Estimate<f64>, String> {
    let mut fitter = BatchFitter::new(config);
    for log in logs {
        fitter.add_log(log, RATE_HZ).map_err(|e| e.to_string())?;
    }
    fitter.estimate().map_err(|e| e.to_string())
}

/// Both models' results of one session (`None` where the fit failed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionResult {
    /// Session seed.
    pub seed: u64,
    /// Offset only ([`Model::Offset`]).
    pub offset_only: Option<Judged>,
    /// Offset and bias with the rest poses ([`Model::OffsetAndAccBias`], the default).
    pub with_bias: Option<Judged>,
    /// The board's estimator on the session's stream, at the second catch.
    pub onboard_at_catch: Option<Judged>,
    /// The board's estimator on the session's stream, after the rest that follows.
    pub onboard_after_rest: Option<Judged>,
    /// `fit imu-offset` on a recording of the same stream.
    pub offline_stream: Option<Judged>,
}

/// How the sessions are drawn and fitted.
#[derive(Debug, Clone, Copy)]
pub struct Plan<'a> {
    /// Accelerometer bias, 1σ per axis (m/s²).
    pub bias_sigma_mps2: f64,
    /// One airframe for every session instead of the cycle through [`AIRFRAMES`].
    pub airframe: Option<&'a Airframe>,
    /// Drag treatment of the fits (`--no-drag` for none).
    pub drag_model: DragModel,
    /// How the spins are drawn.
    pub spins: SpinDraw,
}

/// Draw and fit session `seed`.
pub fn run_session(seed: u64, plan: &Plan<'_>) -> SessionResult {
    let session = Session::drawn(seed, plan.bias_sigma_mps2, plan.airframe, plan.spins);
    let logs = session.logs();
    let truth = session.truth_m();
    let bias = session.acc_bias_mps2;
    let judge =
        |model| fit(&logs, model, plan.drag_model).ok().map(|e| Judged::new(&e, &truth, &bias));
    let (stream, _) = session.stream();
    let (at_catch, after_rest) = onboard(&stream, plan.drag_model);
    let offline_stream =
        fit(std::slice::from_ref(&stream), Model::OffsetAndAccBias, plan.drag_model)
            .ok()
            .map(|e| Judged::new(&e, &truth, &bias));
    SessionResult {
        seed,
        offset_only: judge(Model::Offset),
        with_bias: judge(Model::OffsetAndAccBias),
        onboard_at_catch: at_catch.map(|e| Judged::new(&e, &truth, &bias)),
        onboard_after_rest: after_rest.map(|e| Judged::new(&e, &truth, &bias)),
        offline_stream,
    }
}

/// What a batch of sessions shows for one model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// Sessions fitted.
    pub fits: usize,
    /// Sessions where the fit failed (no estimate).
    pub failed: usize,
    /// Fraction declared well determined.
    pub well_determined: f64,
    /// Fraction with the truth inside the reported 95 % ellipsoid.
    pub coverage: f64,
    /// Error median, 99th percentile and worst (m).
    pub error_median_m: f64,
    pub error_p99_m: f64,
    pub error_max_m: f64,
    /// Median largest 95 % semi-axis (m).
    pub semi_axis_median_m: f64,
    /// Factor the semi-axes would need for exactly 95 % coverage (below 1: too wide).
    pub axes_factor: f64,
    /// Median bias error (m/s²), when the bias was fitted.
    pub bias_error_median_mps2: Option<f64>,
}

impl Summary {
    /// Summarise judged fits (`None` = failed).
    pub fn of(fits: &[Option<Judged>]) -> Self {
        let ok: Vec<&Judged> = fits.iter().flatten().collect();
        let n = ok.len().max(1) as f64;
        let fraction = |f: &dyn Fn(&Judged) -> bool| ok.iter().filter(|j| f(j)).count() as f64 / n;
        let errors: Vec<f64> = ok.iter().map(|j| j.error_m).collect();
        let semi: Vec<f64> = ok.iter().map(|j| j.largest_semi_axis_m).collect();
        let mahalanobis: Vec<f64> = ok.iter().map(|j| j.normalised_mahalanobis).collect();
        let bias: Vec<f64> = ok.iter().filter_map(|j| j.bias_error_mps2).collect();
        Self {
            fits: fits.len(),
            failed: fits.len() - ok.len(),
            well_determined: fraction(&|j| j.well_determined),
            coverage: fraction(&|j| j.normalised_mahalanobis <= 1.0),
            error_median_m: stats::quantile(&errors, 0.5),
            error_p99_m: stats::quantile(&errors, 0.99),
            error_max_m: stats::quantile(&errors, 1.0),
            semi_axis_median_m: stats::quantile(&semi, 0.5),
            axes_factor: stats::quantile(&mahalanobis, 0.95).sqrt(),
            bias_error_median_mps2: (!bias.is_empty()).then(|| stats::quantile(&bias, 0.5)),
        }
    }
}

/// Run `sessions` sessions from `seed` on `threads` workers; `progress` gets the count done.
pub fn monte_carlo(
    sessions: usize,
    seed: u64,
    plan: &Plan<'_>,
    threads: usize,
    progress: &(dyn Fn(usize) + Sync),
) -> Vec<SessionResult> {
    stats::run_seeds(sessions, seed, threads, progress, |s| run_session(s, plan))
}
