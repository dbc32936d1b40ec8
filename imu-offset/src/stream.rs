//! The onboard estimator: free-fall detection, edge trimming and recursive accumulation, `f32`,
//! constant memory (15 KB, of which 10.6 KB hold the drag model's blocks of the throw in
//! progress), no allocation, no panics.
//!
//! # Free-fall detection
//! On the filtered, aligned signals, a sample is in free fall when
//! `|f| < min(acc_floor + max_offset (|Ω̇| + |Ω|²), acc_ceiling)`: in free fall
//! `|f| = |Ω̇ × r + Ω × (Ω × r)|` is bounded by `|r| (|Ω̇| + |Ω|²)`, while in the hand `|f|` is at
//! least about g (holding, even while spinning the craft up) and 2–3 g (throwing, catching); the
//! ceiling keeps a fast spin in the hand from passing as free fall. A run of such samples at least
//! [`Config::min_free_fall_s`] long is a throw.
//!
//! # Trimming, and why samples are held back
//! The first [`Config::trim_start_s`] of a free fall are skipped (the low-pass still carries the
//! hand's force while settling). At the end the free fall is only detected once the catching
//! hand's force has grown past the threshold, so the last [`Config::trim_end_s`] before detection
//! must not count either.
//! A recursive estimator cannot take rows back, so rows are first summed into blocks of
//! [`Config::block_s`]; a finished block waits in a small queue until the free fall has lasted
//! `trim_end_s` beyond it, and only then joins the segment. At the catch the waiting blocks (and the
//! unfinished one) are dropped. The blocks are also what the batch-means variance needs.
//!
//! # Cost
//! Per sample: two 3-axis biquads and a difference (front end), the free-fall test, and one
//! [`OffsetRls`]-style update (build `X`, about 45 multiply-adds into `moments`). The update alone
//! compiles to 145 Cortex-M7 instructions, branch-free (static count from `llvm-objdump` of
//! `OffsetRls::update`, release, LTO, `-C target-cpu=cortex-m7`; to be confirmed by
//! `cargo xtask bench-m7`), and with the drag model a quaternion step and the drag columns' sums
//! (`drag`). Once per block (20 ms) a merge of two moment sets; once per throw the drag model's
//! fold (9 × 9 normal equations in `f64`) and a 3 × 3 Cholesky solve to move the reference offset.

use nalgebra::{Matrix3, Vector3};

use super::drag::{BlockDragSums, DragSums, DragThrow};
use super::front_end::{regressor, AlignedSample, FrontEnd};
use super::moments::{BatchMeans, Moments};
use super::rest::{RestDetector, RestPoses};
use super::solve::{self, Problem};
use super::{
    validate_sample, Config, DragModel, Estimate, ImuOffsetError, ImuSample, Scalar, Segment,
    MAX_RATE_HZ, MAX_SEGMENTS, MIN_RATE_HZ,
};

/// Most finished blocks waiting for the free fall to outlast them by `trim_end_s`
/// (`⌈trim_end / block⌉ + 1` are needed; 8 allows `trim_end_s` up to 7 blocks).
const PENDING_CAPACITY: usize = 8;

/// Shortest segment kept after trimming, in blocks (fewer cannot say much about `r`).
const MIN_SEGMENT_BLOCKS: u32 = 2;

/// One aligned sample as a row of eq. 3 relative to `r_ref`: `(X, y' = f − X r_ref, Ω)`.
/// Shared by the onboard and the batch estimator, so both use identical rows.
#[inline]
pub(crate) fn aligned_row<T: Scalar>(
    s: &AlignedSample,
    r_ref: &Vector3<T>,
) -> (Matrix3<T>, Vector3<T>, Vector3<T>) {
    let w = s.gyro_radps.map(T::from);
    let w_dot = s.gyro_dot_radps2.map(T::from);
    let x = regressor(&w, &w_dot);
    let y = s.acc_mps2.map(T::from) - x * r_ref;
    (x, y, w)
}

/// Add one aligned sample to `moments` as a row of eq. 3 relative to `r_ref`.
#[inline]
pub(crate) fn accumulate_aligned<T: Scalar>(
    moments: &mut Moments<T>,
    s: &AlignedSample,
    r_ref: &Vector3<T>,
) {
    let (x, y, _) = aligned_row(s, r_ref);
    moments.accumulate(&x, &y);
}

/// Recursive least squares for eq. 3 alone, in information form (forgetting factor 1): the unit
/// that `cargo xtask bench-m7` counts as "one IMU-offset RLS update". [`OffsetRls::estimate`]
/// equals batch least squares over the same rows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffsetRls {
    moments: Moments<f32>,
    r_ref_m: Vector3<f32>,
}

impl OffsetRls {
    /// No data; measurements are taken relative to `r_ref_m` (any prior guess, e.g. zero).
    pub fn new(r_ref_m: Vector3<f32>) -> Self {
        Self { moments: Moments::new(), r_ref_m }
    }

    /// Add one aligned sample (build `X(Ω, Ω̇)`, accumulate the normal equations).
    #[inline]
    pub fn update(&mut self, sample: &AlignedSample) {
        accumulate_aligned(&mut self.moments, sample, &self.r_ref_m);
    }

    /// Least-squares `r̂` (m) over all rows so far, or `None` while unobservable.
    pub fn estimate(&self) -> Option<Vector3<f32>> {
        solve::offset_only(&self.moments, &self.r_ref_m)
    }

    /// Rows accumulated.
    pub fn rows(&self) -> u32 {
        self.moments.count
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Not in free fall.
    Held,
    /// In free fall since aligned sample `start`.
    Falling { start: u32 },
}

/// A finished block waiting to be committed, with its end index (exclusive).
#[derive(Debug, Clone, Copy, PartialEq)]
struct PendingBlock {
    moments: Moments<f32>,
    drag: BlockDragSums<f32>,
    end: u32,
}

/// Streaming IMU-offset estimator for the board (see the module documentation).
#[derive(Debug, Clone)]
pub struct ImuOffsetEstimator {
    config: Config,
    rate_hz: f32,
    settings: Settings,
    state: State,
    /// The drag model's store of the throw in progress ([`DragModel::VerticalQuadratic`]):
    /// 10.6 KB, kept out of [`State`] so that a restart clears it in place.
    drag_throw: DragThrow<f32>,
}

/// What the configuration fixes, validated: sample counts and the front end's design.
#[derive(Debug, Clone, Copy)]
struct Settings {
    /// The front end as configured, before any sample.
    front: FrontEnd,
    trim_start_len: u32,
    trim_end_len: u32,
    block_len: u32,
    min_free_fall_len: u32,
    /// Blocks per long batch.
    group: u32,
}

impl Settings {
    /// Validate `config` for a stream at `rate_hz`.
    fn new(rate_hz: f32, config: &Config) -> Result<Self, ImuOffsetError> {
        let front = FrontEnd::new(config.cutoff_hz, rate_hz)
            .map_err(|_| ImuOffsetError::InvalidConfig("cutoff_hz must be in (0, rate/4]"))?;
        let samples = |seconds: f32, what: &'static str| {
            let n = libm::roundf(seconds * rate_hz);
            if seconds.is_finite() && (0.0..=1.0e6).contains(&n) {
                Ok(n as u32)
            } else {
                Err(ImuOffsetError::InvalidConfig(what))
            }
        };
        let trim_start_len = samples(config.trim_start_s, "trim_start_s must be finite, ≥ 0")?;
        let trim_end_len = samples(config.trim_end_s, "trim_end_s must be finite, ≥ 0")?;
        let block_len = samples(config.block_s, "block_s must be finite and positive")?;
        let min_free_fall_len = samples(config.min_free_fall_s, "min_free_fall_s out of range")?;
        if block_len < 2 {
            return Err(ImuOffsetError::InvalidConfig("block_s must span at least 2 samples"));
        }
        if trim_end_len.div_ceil(block_len) as usize + 1 > PENDING_CAPACITY {
            return Err(ImuOffsetError::InvalidConfig("trim_end_s may be at most 7 × block_s"));
        }
        let positive = |v: f32| v.is_finite() && v > 0.0;
        if !(positive(config.acc_floor_mps2)
            && positive(config.acc_ceiling_mps2)
            && config.max_offset_m.is_finite())
            || config.max_offset_m < 0.0
        {
            return Err(ImuOffsetError::InvalidConfig("free-fall thresholds out of range"));
        }
        if !(positive(config.gravity_mps2) && positive(config.gravity_sigma_mps2)) {
            return Err(ImuOffsetError::InvalidConfig("gravity and its sigma must be positive"));
        }
        let fraction = |v: f32| (0.0..=0.2).contains(&v);
        if !(fraction(config.scale_error_sigma) && fraction(config.cross_axis_sigma)) {
            return Err(ImuOffsetError::InvalidConfig("sensitivity errors outside 0–20 %"));
        }
        if !positive(config.max_semi_axis_m) {
            return Err(ImuOffsetError::InvalidConfig("max_semi_axis_m must be positive"));
        }
        let group = libm::roundf(config.long_batch_s / config.block_s);
        if !(1.0..=1000.0).contains(&group) {
            return Err(ImuOffsetError::InvalidConfig("long_batch_s must be 1 to 1000 blocks"));
        }
        Ok(Self {
            front,
            trim_start_len,
            trim_end_len,
            block_len,
            min_free_fall_len,
            group: group as u32,
        })
    }
}

/// Everything the stream has taught the estimator (3.6 KB), cleared by a restart.
#[derive(Debug, Clone)]
struct State {
    front: FrontEnd,
    phase: Phase,
    /// Reference offset the moments are relative to (m); moved to `r̂` after each throw.
    r_ref_m: Vector3<f32>,
    block: Moments<f32>,
    /// FIFO of finished blocks: `pending[(pending_head + k) % PENDING_CAPACITY]`, `k < pending_len`.
    pending: [PendingBlock; PENDING_CAPACITY],
    pending_head: usize,
    pending_len: usize,
    /// Committed rows and block sums of the throw in progress, and its first used / next index.
    segment_rows: Moments<f32>,
    segment_batches: BatchMeans<f32>,
    segment_first: u32,
    segment_end: u32,
    /// All accepted throws.
    rows: Moments<f32>,
    batches: BatchMeans<f32>,
    segments: [Segment; MAX_SEGMENTS],
    segments_len: usize,
    segments_ignored: u32,
    /// Rest poses between throws (the accelerometer bias, see `rest`).
    rest: RestDetector,
    rest_poses: RestPoses,
    /// Every accepted throw with its drag vector profiled out (relative to `r_ref_m`), with
    /// [`DragModel::VerticalQuadratic`].
    drag: DragSums,
    /// Free falls not used because they outlasted the drag model's block store.
    throws_too_long: u32,
}

impl State {
    fn new(settings: &Settings, rate_hz: f32, gravity_mps2: f32) -> Self {
        let empty = PendingBlock { moments: Moments::new(), drag: BlockDragSums::new(), end: 0 };
        Self {
            front: settings.front,
            phase: Phase::Held,
            r_ref_m: Vector3::zeros(),
            block: Moments::new(),
            pending: [empty; PENDING_CAPACITY],
            pending_head: 0,
            pending_len: 0,
            segment_rows: Moments::new(),
            segment_batches: BatchMeans::new(settings.group),
            segment_first: 0,
            segment_end: 0,
            rows: Moments::new(),
            batches: BatchMeans::new(settings.group),
            segments: [Segment { start_index: 0, end_index: 0 }; MAX_SEGMENTS],
            segments_len: 0,
            segments_ignored: 0,
            rest: RestDetector::new(rate_hz, gravity_mps2),
            rest_poses: RestPoses::new(),
            drag: DragSums::new(),
            throws_too_long: 0,
        }
    }
}

impl ImuOffsetEstimator {
    /// An estimator for a stream at `rate_hz` (500 Hz – 8 kHz).
    pub fn new(rate_hz: f32, config: Config) -> Result<Self, ImuOffsetError> {
        let mut estimator = core::mem::MaybeUninit::uninit();
        Self::build_in(&mut estimator, rate_hz, config)?;
        // SAFETY: `build_in` returned `Ok`: every field is written.
        Ok(unsafe { estimator.assume_init() })
    }

    /// [`Self::new`] written in place into `slot` (15 KB: the board builds it in its background
    /// task's static state, `flight::slot::Slot`). On an error nothing is written.
    pub fn build_in(
        slot: &mut core::mem::MaybeUninit<Self>,
        rate_hz: f32,
        config: Config,
    ) -> Result<&mut Self, ImuOffsetError> {
        if !(rate_hz.is_finite() && (MIN_RATE_HZ..=MAX_RATE_HZ).contains(&rate_hz)) {
            return Err(ImuOffsetError::RateOutOfRange { rate_hz });
        }
        let settings = Settings::new(rate_hz, &config)?;
        let this = slot.as_mut_ptr();
        // SAFETY: `this` is the slot's, valid for writes and aligned; each field is written
        // exactly once before the reference is formed.
        unsafe {
            core::ptr::addr_of_mut!((*this).config).write(config);
            core::ptr::addr_of_mut!((*this).rate_hz).write(rate_hz);
            core::ptr::addr_of_mut!((*this).state).write(State::new(
                &settings,
                rate_hz,
                config.gravity_mps2,
            ));
            core::ptr::addr_of_mut!((*this).settings).write(settings);
            DragThrow::init_in(core::ptr::addr_of_mut!((*this).drag_throw), rate_hz);
            Ok(slot.assume_init_mut())
        }
    }

    /// Forget everything and start again with `config`, in place (the board's background task
    /// restarts a calibration without a 15 KB temporary on its stack). An invalid `config` is
    /// refused and changes nothing.
    pub fn restart(&mut self, config: Config) -> Result<(), ImuOffsetError> {
        let settings = Settings::new(self.rate_hz, &config)?;
        self.state = State::new(&settings, self.rate_hz, config.gravity_mps2);
        self.settings = settings;
        self.config = config;
        self.drag_throw.begin();
        Ok(())
    }

    /// Feed the next raw sample (the control-rate path: bounded time, no allocation, no panic).
    ///
    /// Returns the segment when a throw has just been accepted. A non-finite or impossible sample
    /// is rejected with an error, the throw in progress (if any) is discarded, and the filters
    /// restart; sample indices keep counting so later segments still map to stream time.
    pub fn update(&mut self, sample: &ImuSample) -> Result<Option<Segment>, ImuOffsetError> {
        if let Err(e) = validate_sample(sample, self.next_index()) {
            self.state.front.skip();
            self.state.front.restart();
            self.abandon_free_fall();
            self.end_rest();
            return Err(e);
        }
        Ok(self.state.front.update(sample).and_then(|s| self.process(&s)))
    }

    /// `missing` samples were lost upstream (a gap in the stream): the filters restart and a
    /// throw in progress is abandoned, since Ω̇ and the filtered signals across a gap would be
    /// wrong; indices skip the gap so later segments still map to stream time.
    pub fn gap(&mut self, missing: u32) {
        self.state.front.skip_many(missing);
        self.state.front.restart();
        self.abandon_free_fall();
        self.end_rest();
    }

    /// End of the stream: a free fall still in progress ends here (trimmed as at a catch), and
    /// so does a rest pose.
    pub fn finish(&mut self) -> Option<Segment> {
        self.end_rest();
        match self.state.phase {
            Phase::Falling { start } => {
                let end = self.next_index().saturating_sub(1);
                self.end_free_fall(start, end)
            }
            Phase::Held => None,
        }
    }

    /// The estimate over all accepted throws so far, with the rest poses found so far and the
    /// one in progress as if it ended now (so that it equals the offline fit of a log that ends
    /// here). Call from a background task: it performs a few 3 × 3 and 6 × 6 solves and a 3 × 3
    /// eigen-decomposition.
    pub fn estimate(&self) -> Result<Estimate<f32>, ImuOffsetError> {
        if self.state.segments_len == 0 {
            return Err(ImuOffsetError::NoFreeFall);
        }
        let mut rest_poses = self.state.rest_poses;
        if let Some(pose) = self.state.rest.in_progress() {
            rest_poses.push(pose);
        }
        let problem = Problem {
            rows: &self.state.rows,
            batches: &self.state.batches,
            block_len: self.settings.block_len,
            r_ref: self.state.r_ref_m,
            drag: self.drag_modelled().then_some(&self.state.drag),
            rest: Some(rest_poses.model(&self.config)),
        };
        solve::estimate(&problem, &self.config)
    }

    /// Rest poses found so far (each an attitude held still; see `rest`), not counting the one
    /// in progress.
    pub fn rest_poses(&self) -> u32 {
        self.state.rest_poses.as_slice().len() as u32
    }

    /// How much rest the estimate has seen: finished poses and the blocks of the one in
    /// progress. It changes whenever [`Self::estimate`] would change without a new throw.
    pub fn rest_progress(&self) -> (u32, u32) {
        (self.rest_poses(), self.state.rest.kept_blocks())
    }

    /// The rest poses, for the batch fitter (which uses exactly the poses found here).
    pub(crate) fn rest_pose_list(&self) -> &RestPoses {
        &self.state.rest_poses
    }

    /// The accepted throws, in order.
    pub fn segments(&self) -> &[Segment] {
        self.state.segments.get(..self.state.segments_len).unwrap_or(&[])
    }

    /// Throws accepted after [`MAX_SEGMENTS`] was reached, and therefore ignored.
    pub fn segments_ignored(&self) -> u32 {
        self.state.segments_ignored
    }

    /// Free falls not used because they lasted longer than the drag model keeps
    /// ([`MAX_THROW_BLOCKS`](super::MAX_THROW_BLOCKS) blocks: 1.6 s at the default block length).
    pub fn throws_too_long(&self) -> u32 {
        self.state.throws_too_long
    }

    fn drag_modelled(&self) -> bool {
        self.config.drag_model == DragModel::VerticalQuadratic
    }

    /// True while a free fall is in progress.
    pub fn in_free_fall(&self) -> bool {
        matches!(self.state.phase, Phase::Falling { .. })
    }

    /// Samples (rows of eq. 3) in the accepted throws.
    pub fn samples_used(&self) -> u32 {
        self.state.rows.count
    }

    /// The stream's sample rate (Hz).
    pub fn rate_hz(&self) -> f32 {
        self.rate_hz
    }

    /// The configuration in use.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Shortest accepted free fall (samples).
    pub(crate) fn min_free_fall_len(&self) -> u32 {
        self.settings.min_free_fall_len
    }

    /// Blocks per long batch of the batch-means variance.
    pub(crate) fn long_batch_blocks(&self) -> u32 {
        self.state.batches.group
    }

    /// Rows per block (samples).
    pub(crate) fn block_len(&self) -> u32 {
        self.settings.block_len
    }

    fn next_index(&self) -> u32 {
        self.state.front.next_index()
    }

    fn is_free_fall(&self, s: &AlignedSample) -> bool {
        let rotational_bound_mps2 = self.config.acc_floor_mps2
            + self.config.max_offset_m * (s.gyro_dot_radps2.norm() + s.gyro_radps.norm_squared());
        s.acc_mps2.norm() < rotational_bound_mps2.min(self.config.acc_ceiling_mps2)
    }

    fn process(&mut self, s: &AlignedSample) -> Option<Segment> {
        let free = self.is_free_fall(s);
        match self.state.phase {
            Phase::Held => {
                if free {
                    self.end_rest();
                    self.begin_free_fall(s.index);
                } else if let Some(pose) = self.state.rest.update(s) {
                    self.state.rest_poses.push(pose);
                }
                None
            }
            Phase::Falling { start } if !free => self.end_free_fall(start, s.index),
            Phase::Falling { start } => {
                if s.index >= start.saturating_add(self.settings.trim_start_len) {
                    let (x, y, w) = aligned_row(s, &self.state.r_ref_m);
                    self.state.block.accumulate(&x, &y);
                    if self.drag_modelled() {
                        self.drag_throw.add_row(&x, &y, &w);
                    }
                    if self.state.block.count >= self.settings.block_len {
                        let end = s.index.saturating_add(1);
                        self.push_pending(end);
                    }
                }
                self.commit_ready(s.index.saturating_add(1));
                None
            }
        }
    }

    /// A rest pose in progress ends; it is kept when long enough.
    fn end_rest(&mut self) {
        if let Some(pose) = self.state.rest.end() {
            self.state.rest_poses.push(pose);
        }
    }

    fn begin_free_fall(&mut self, start: u32) {
        self.state.phase = Phase::Falling { start };
        self.state.block = Moments::new();
        self.state.pending_len = 0;
        self.state.segment_rows = Moments::new();
        self.state.segment_batches = BatchMeans::new(self.state.batches.group);
        self.state.segment_first = start.saturating_add(self.settings.trim_start_len);
        self.state.segment_end = self.state.segment_first;
        self.drag_throw.begin();
    }

    fn abandon_free_fall(&mut self) {
        self.state.phase = Phase::Held;
        self.state.block = Moments::new();
        self.state.pending_len = 0;
    }

    fn push_pending(&mut self, end: u32) {
        let block = core::mem::replace(&mut self.state.block, Moments::new());
        let drag = self.drag_throw.take_block();
        if self.state.pending_len >= PENDING_CAPACITY {
            // Unreachable with a validated configuration; dropping keeps the rollback safe.
            return;
        }
        let slot = (self.state.pending_head + self.state.pending_len) % PENDING_CAPACITY;
        if let Some(p) = self.state.pending.get_mut(slot) {
            *p = PendingBlock { moments: block, drag, end };
            self.state.pending_len += 1;
        }
    }

    /// Commit every waiting block that ends at least `trim_end_len` before `limit` (the first index
    /// that may be contaminated by the catch is `limit` or later).
    fn commit_ready(&mut self, limit: u32) {
        while self.state.pending_len > 0 {
            let Some(&oldest) = self.state.pending.get(self.state.pending_head) else { return };
            if oldest.end.saturating_add(self.settings.trim_end_len) > limit {
                return;
            }
            self.state.segment_rows.merge(&oldest.moments);
            self.state.segment_batches.add_block(&oldest.moments);
            if self.drag_modelled() {
                let m = &oldest.moments;
                self.drag_throw.commit(&m.xsum, &m.ysum, oldest.drag);
            }
            self.state.segment_end = oldest.end;
            self.state.pending_head = (self.state.pending_head + 1) % PENDING_CAPACITY;
            self.state.pending_len -= 1;
        }
    }

    /// Free fall from aligned index `start` ended at `end` (first sample no longer free).
    fn end_free_fall(&mut self, start: u32, end: u32) -> Option<Segment> {
        self.commit_ready(end);
        self.abandon_free_fall();
        let long_enough = end.saturating_sub(start) >= self.settings.min_free_fall_len
            && self.state.segment_batches.short.count >= MIN_SEGMENT_BLOCKS;
        if !long_enough {
            return None;
        }
        if self.drag_modelled() && self.drag_throw.overflowed() {
            self.state.throws_too_long = self.state.throws_too_long.saturating_add(1);
            return None;
        }
        let segment =
            Segment { start_index: self.state.segment_first, end_index: self.state.segment_end };
        let Some(slot) = self.state.segments.get_mut(self.state.segments_len) else {
            self.state.segments_ignored = self.state.segments_ignored.saturating_add(1);
            return None;
        };
        *slot = segment;
        self.state.segments_len += 1;
        self.state.rows.merge(&self.state.segment_rows);
        self.state.batches.merge(&self.state.segment_batches);
        if self.drag_modelled() {
            let (rows, group) = (&self.state.segment_rows, self.state.batches.group);
            let throw = &self.drag_throw;
            self.state.drag.add_throw(
                throw,
                rows,
                &segment,
                self.settings.block_len,
                group,
                self.rate_hz,
            );
        }
        // Move the reference to the new estimate so later sums stay small (f32 precision).
        if let Some(r) = solve::offset_only(&self.state.rows, &self.state.r_ref_m) {
            let delta = r - self.state.r_ref_m;
            self.state.rows.recentre(&delta);
            self.state.batches.recentre(&delta);
            self.state.drag.recentre(&delta.cast::<f64>());
            self.state.r_ref_m = r;
        }
        Some(segment)
    }
}
