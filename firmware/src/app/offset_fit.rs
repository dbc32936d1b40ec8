//! The in-flight IMU-offset fit (`imu_offset::in_flight`) as a task of its own, below the
//! background task's learner: on the board it runs in `idle`, with whatever time the three
//! prioritised tasks leave.
//!
//! Why: beside the learner, the fit's filters and sums were the background task's worst sample
//! (the learner's 15,646 Cortex-M7 instructions plus the fit's 9,811 on the octorotor: 31.3 % of
//! the 2 kHz period at the planned cycles per instruction, against the 25 % of issue 56), and no
//! spreading of either could reach a quarter: the two averaged 19,800 a sample against the
//! 17,100 a quarter leaves them. The fit has no deadline of its own. Its result is used once it
//! is usable, after about 2 s of flight; a few milliseconds more change nothing. So it runs where
//! nothing waits for it, and the background task's share of it is handing each sample over.
//!
//! How, and why the result is the same on every machine:
//! - The background task ([`FitClient`]) pushes the fit's work into a ring, tagged with the
//!   number of the background sample it came with: the start of an attempt, each sample (the
//!   reported speeds, or without speed telemetry the learner's released samples), an advance on
//!   the samples in between, a stop.
//! - The worker ([`OffsetFitWorker`]) takes the work in order and, every
//!   [`OFFSET_FIT_SOLVE_INTERVAL_S`] of fitted samples, solves and hands the estimate back in a
//!   second ring, tagged with the sample that completed it.
//! - The background task applies an estimate exactly [`OFFSET_FIT_HANDBACK_S`] after the
//!   sample that completed it, never when it happens to arrive: before each sample it checks
//!   that the worker has finished all the work pushed up to that many samples ago (and that the
//!   ring has room for a sample's work), and when it has not, it leaves the sample in its queue
//!   and returns; the worker then has the processor. The learner's results therefore depend only
//!   on the samples, on the board, in the simulator and in a replay of the board's log alike.
//! - What that costs: an estimate reaches the learner 5 ms later than it did inline, and the
//!   background task waits when the worker is more than that behind: on the board, for at most
//!   about 0.7 ms after a solve at the planned cycles per instruction (docs/budget.md), its
//!   samples held in their queue (32 ms); beyond that they would be dropped and counted, as for
//!   any slow background task.

use super::hal::MAX_MOTORS;
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicU32, Ordering};
use heapless::spsc::{Consumer, Producer, Queue};
use imu_offset::in_flight::{OffsetFit, OffsetFitEstimate, SolveScratch};

/// How often the in-flight IMU-offset fit is solved while it takes samples, s (two Cholesky
/// inverses each, 8 × 8 and 33 × 33: about 1.07 M Cortex-M7 instructions on the octorotor,
/// docs/benchmarks.md).
pub const OFFSET_FIT_SOLVE_INTERVAL_S: f32 = 0.1;

/// How long after the sample that completed it an estimate is applied, s (ours): about the
/// solve's time in the idle time the worst control period leaves (1.07 M instructions on the
/// octorotor, 4.0 ms at 1.5 cycles an instruction and 400 MHz, 5.7 ms in the 76 % left idle;
/// 1.9 ms at 0.7), so that the background task waits for the worker rarely and briefly
/// (`cargo xtask bench-m7` checks the longest wait against half its sample queue). Short,
/// because an estimate that comes back after the engagement is not the one the controller is
/// formed on: two sets of 1,000 random worlds with no offset known (`fly monte-carlo --world
/// random --unknown-imu-offset`, seeds 1–1000 and 1001–2000) held 997 + 2 and 996 + 4 with the
/// fit inline, 997 + 2 and 995 + 4 at 5 ms (seed 1095, engaged 4.6 m up falling at 2 m/s, hit
/// the ground; inline and at 20 ms it held), 996 + 2 and 995 + 5 at 20 ms (429 and 1276 engaged
/// just before an estimate came back, on the learner's unfitted rows). At most
/// [`HANDBACK_HISTORY`] − 1 samples (5 ms up to 12.6 kHz; shorter above).
pub const OFFSET_FIT_HANDBACK_S: f32 = 0.005;

/// Samples of pushed-work counts the client remembers: longer than the hand-back.
const HANDBACK_HISTORY: usize = 64;

/// The work ring's capacity, items (about 80 B each). The client waits for the worker to be
/// within the hand-back, one item a sample, so it holds about 11 at 2 kHz, and as many more as
/// samples the background task processes in one run after a wait.
pub const FIT_WORK_LEN: usize = 64;

/// The estimates' ring: one solve every 0.1 s of fitted samples against a 5 ms hand-back, and
/// the client takes every due one on every sample (those of an abandoned attempt too), so it
/// holds one at a time; the worker waits while it is full.
const ESTIMATES_LEN: usize = 4;

/// Most work items one background sample pushes: a start or a stop, and a sample or an advance
/// (the learner releases at most `flight::learner::no_speed::RELEASE_PER_SAMPLE` a sample).
pub const MAX_FIT_WORK_PER_SAMPLE: usize = 2 + flight::learner::no_speed::RELEASE_PER_SAMPLE;

/// One piece of the fit's work.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FitWork {
    /// A new attempt (`epoch`, counted by the client) for `motors` motors sampled at `rate_hz`,
    /// with speeds `lag_s` older than the IMU samples ([`OffsetFit::reset`]).
    Start { epoch: u16, motors: u8, rate_hz: f32, lag_s: f32 },
    /// One sample ([`OffsetFit::update`]): gyro (rad/s), accelerometer (m/s²), the motors'
    /// speeds (rad/s, NaN where none was reported) and the velocity (m/s), IMU axes.
    Sample {
        gyro_rad_s: [f32; 3],
        accel_mps2: [f32; 3],
        speeds_rad_s: [f32; MAX_MOTORS],
        velocity_imu_mps: [f32; 3],
    },
    /// A background sample with no sample for the fit ([`OffsetFit::advance`]).
    Advance,
    /// The attempt's fit is abandoned.
    Stop,
}

/// Work with the number of the background sample that pushed it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitItem {
    pub tag: u32,
    pub work: FitWork,
}

/// A solve's outcome: the attempt, the background sample whose work completed it, the estimate
/// (`None`: not determined yet).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOutput {
    pub tag: u32,
    pub epoch: u16,
    pub estimate: Option<OffsetFitEstimate>,
}

/// The two rings and the worker's progress: split once, at start-up, into the background
/// task's end and the worker's ([`FitHandoff::split`]).
pub struct FitHandoff {
    work: Queue<FitItem, FIT_WORK_LEN>,
    estimates: Queue<FitOutput, ESTIMATES_LEN>,
    /// Items the worker has finished, wrapping.
    processed: AtomicU32,
}

impl Default for FitHandoff {
    fn default() -> Self {
        Self::new()
    }
}

impl FitHandoff {
    /// Empty rings.
    pub const fn new() -> Self {
        Self { work: Queue::new(), estimates: Queue::new(), processed: AtomicU32::new(0) }
    }

    /// The background task's end, at `rate_hz` samples a second, and the worker's.
    pub fn split(&mut self, rate_hz: f32) -> (FitClient<'_>, FitWorkerEnds<'_>) {
        let (work_in, work_out) = self.work.split();
        let (estimates_in, estimates_out) = self.estimates.split();
        let handback = libm::roundf(OFFSET_FIT_HANDBACK_S * rate_hz.max(0.0)) as usize;
        let client = FitClient {
            work: work_in,
            estimates: estimates_out,
            processed: &self.processed,
            pushed: 0,
            pushed_after: [0; HANDBACK_HISTORY],
            handback_samples: handback.clamp(1, HANDBACK_HISTORY - 1) as u32,
            epoch: 0,
        };
        (
            client,
            FitWorkerEnds { work: work_out, estimates: estimates_in, processed: &self.processed },
        )
    }
}

/// Whether wrapping count `a` has reached `b`.
fn reached(a: u32, b: u32) -> bool {
    a.wrapping_sub(b) < u32::MAX / 2
}

/// The background task's end.
pub struct FitClient<'q> {
    work: Producer<'q, FitItem>,
    estimates: Consumer<'q, FitOutput>,
    processed: &'q AtomicU32,
    /// Items pushed so far, wrapping.
    pushed: u32,
    /// [`Self::pushed`] after each sample, by sample number modulo the history.
    pushed_after: [u32; HANDBACK_HISTORY],
    /// [`OFFSET_FIT_HANDBACK_S`] in samples.
    handback_samples: u32,
    /// The latest attempt.
    epoch: u16,
}

impl FitClient<'_> {
    /// Whether sample `tag` may be processed now: the ring has room for its work, and the worker
    /// has finished all the work pushed up to the hand-back before it (whose estimates it
    /// applies).
    pub fn ready_for(&self, tag: u32) -> bool {
        if self.work.capacity() - self.work.len() < MAX_FIT_WORK_PER_SAMPLE {
            return false;
        }
        let due = tag.wrapping_sub(self.handback_samples);
        let needed = self.pushed_after[due as usize % HANDBACK_HISTORY];
        reached(self.processed.load(Ordering::Acquire), needed)
    }

    /// A new attempt, pushed with sample `tag`: the estimates of earlier ones are ignored from
    /// now on.
    pub fn start(&mut self, tag: u32, motors: u8, rate_hz: f32, lag_s: f32) {
        self.epoch = self.epoch.wrapping_add(1);
        let epoch = self.epoch;
        self.push(tag, FitWork::Start { epoch, motors, rate_hz, lag_s });
    }

    /// The attempt's fit abandoned, with sample `tag`.
    pub fn stop(&mut self, tag: u32) {
        self.epoch = self.epoch.wrapping_add(1);
        self.push(tag, FitWork::Stop);
    }

    /// Work for the worker, with sample `tag`. `false`: the ring was full (a sample pushed more
    /// than [`MAX_FIT_WORK_PER_SAMPLE`], or was processed without [`Self::ready_for`]) and the
    /// work is lost: the caller abandons the attempt's fit.
    pub fn push(&mut self, tag: u32, work: FitWork) -> bool {
        let pushed = self.work.enqueue(FitItem { tag, work }).is_ok();
        if pushed {
            self.pushed = self.pushed.wrapping_add(1);
        }
        pushed
    }

    /// Sample `tag` is done: what it pushed counts towards its hand-back.
    pub fn end_sample(&mut self, tag: u32) {
        self.pushed_after[tag as usize % HANDBACK_HISTORY] = self.pushed;
    }

    /// The latest attempt's estimates due at sample `tag` (completed the hand-back before it or
    /// earlier), oldest first; earlier attempts' are dropped.
    pub fn take_due(&mut self, tag: u32, mut apply: impl FnMut(Option<OffsetFitEstimate>)) {
        let due = tag.wrapping_sub(self.handback_samples);
        while let Some(output) = self.estimates.peek() {
            if !reached(due, output.tag) {
                break;
            }
            let output = *output;
            self.estimates.dequeue();
            if output.epoch == self.epoch {
                apply(output.estimate);
            }
        }
    }
}

/// The worker's ends of the rings, for [`OffsetFitWorker::build_in`].
pub struct FitWorkerEnds<'q> {
    work: Consumer<'q, FitItem>,
    estimates: Producer<'q, FitOutput>,
    processed: &'q AtomicU32,
}

/// The fit and its solve's work areas, fed by the ring.
pub struct OffsetFitWorker<'q> {
    ends: FitWorkerEnds<'q>,
    /// Items finished, wrapping (published in the handoff).
    processed: u32,
    /// Reset in place for each attempt (14 KB), never moved.
    fit: OffsetFit,
    /// Whether the current attempt fits.
    fitting: bool,
    epoch: u16,
    /// The solve's matrices (26 KB), here rather than on the stack.
    scratch: SolveScratch,
}

impl<'q> OffsetFitWorker<'q> {
    /// The worker in place, field by field (40 KB: on the board a static that `init` builds).
    pub fn build_in<'s>(slot: &'s mut MaybeUninit<Self>, ends: FitWorkerEnds<'q>) -> &'s mut Self {
        let worker = slot.as_mut_ptr();
        // SAFETY: each field is written exactly once through raw field pointers before the
        // reference is formed; zero bytes are a valid fit and scratch (plain numbers).
        unsafe {
            addr_of_mut!((*worker).ends).write(ends);
            addr_of_mut!((*worker).processed).write(0);
            addr_of_mut!((*worker).fit).write_bytes(0, 1);
            addr_of_mut!((*worker).fitting).write(false);
            addr_of_mut!((*worker).epoch).write(0);
            addr_of_mut!((*worker).scratch).write_bytes(0, 1);
            slot.assume_init_mut()
        }
    }

    /// The worker by value (the host's; 40 KB on the stack).
    pub fn new(ends: FitWorkerEnds<'q>) -> Self {
        let mut slot = MaybeUninit::uninit();
        Self::build_in(&mut slot, ends);
        // SAFETY: `build_in` wrote every field.
        unsafe { slot.assume_init() }
    }

    /// Everything waiting, in order; stops early only while the estimates' ring is full.
    /// Returns the items processed.
    pub fn run_pending(&mut self) -> u32 {
        let mut processed = 0;
        while self.ends.estimates.ready() {
            let Some(item) = self.ends.work.dequeue() else { break };
            self.process(item);
            processed += 1;
            self.processed = self.processed.wrapping_add(1);
            self.ends.processed.store(self.processed, Ordering::Release);
        }
        processed
    }

    fn process(&mut self, item: FitItem) {
        match item.work {
            FitWork::Start { epoch, motors, rate_hz, lag_s } => {
                self.epoch = epoch;
                self.fitting = self.fit.reset(usize::from(motors), rate_hz, lag_s);
            }
            FitWork::Stop => self.fitting = false,
            FitWork::Sample { gyro_rad_s, accel_mps2, speeds_rad_s, velocity_imu_mps } => {
                if self.fitting {
                    let before = self.fit.samples();
                    let motors = self.fit.motors();
                    self.fit.update(
                        gyro_rad_s,
                        accel_mps2,
                        &speeds_rad_s[..motors],
                        velocity_imu_mps,
                    );
                    self.solve_if_due(before, item.tag);
                }
            }
            FitWork::Advance => {
                if self.fitting {
                    let before = self.fit.samples();
                    self.fit.advance();
                    self.solve_if_due(before, item.tag);
                }
            }
        }
    }

    /// Solved when the sums have grown by an interval's worth (the fit sums one sample in every
    /// few: counting its own samples).
    fn solve_if_due(&mut self, before: u32, tag: u32) {
        let per_solve = libm::roundf(OFFSET_FIT_SOLVE_INTERVAL_S * self.fit.sum_rate_hz()).max(1.0);
        let summed = self.fit.samples();
        if summed != before && summed.is_multiple_of(per_solve as u32) {
            let estimate = self.fit.estimate_in(&mut self.scratch).ok();
            // Room was checked before the item was taken (`run_pending`).
            let _ = self.ends.estimates.enqueue(FitOutput { tag, epoch: self.epoch, estimate });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Motion enough for the fit to solve: a pseudo-random but repeatable stream.
    fn sample(tag: u32) -> FitWork {
        let x = |k: u32| {
            let h = (tag.wrapping_mul(2_654_435_761) ^ k.wrapping_mul(40_503)) % 10_007;
            h as f32 / 10_007.0 - 0.5
        };
        FitWork::Sample {
            gyro_rad_s: [4.0 * x(1), 4.0 * x(2), 2.0 * x(3)],
            accel_mps2: [3.0 * x(4), 3.0 * x(5), -9.8 + 3.0 * x(6)],
            speeds_rad_s: core::array::from_fn(|i| 900.0 + 300.0 * x(7 + i as u32)),
            velocity_imu_mps: [x(20), x(21), x(22)],
        }
    }

    /// The background's side of `samples` samples, with the worker run whenever `run_now` says
    /// (and whenever the client must wait): each estimate applied, with the sample it was
    /// applied at; and how often the client waited.
    fn fly(
        samples: u32,
        restart_at: Option<u32>,
        mut run_now: impl FnMut(u32) -> bool,
    ) -> (Vec<(u32, Option<OffsetFitEstimate>)>, u32) {
        let mut handoff = FitHandoff::new();
        let (mut client, ends) = handoff.split(2000.0);
        let mut worker = OffsetFitWorker::new(ends);
        let (mut applied, mut waited) = (Vec::new(), 0);
        for tag in 1..=samples {
            while !client.ready_for(tag) {
                waited += 1;
                assert!(worker.run_pending() > 0, "the client waits for a worker with no work");
            }
            if tag == 1 || restart_at == Some(tag) {
                client.start(tag, 4, 2000.0, 0.0);
            }
            assert!(client.push(tag, sample(tag)));
            client.end_sample(tag);
            client.take_due(tag, |estimate| applied.push((tag, estimate)));
            if run_now(tag) {
                worker.run_pending();
            }
        }
        (applied, waited)
    }

    /// The estimates reach the background task a fixed 20 ms after the sample that completed
    /// them, whether the worker keeps up with every sample (the simulator) or runs only when
    /// the background task has to wait for it (a board with no time to spare): the learner's
    /// results depend on the samples alone.
    #[test]
    fn estimates_come_back_a_fixed_time_after_their_sample_however_late_the_worker_runs() {
        let (on_time, waited) = fly(2_000, None, |_| true);
        assert_eq!(waited, 0);
        let (late, waited) = fly(2_000, None, |_| false);
        assert!(waited > 0, "the late worker never held the client up");
        assert_eq!(late, on_time);
        // Every 0.1 s of fitted samples, each applied the hand-back after the sample that
        // completed it.
        assert!(on_time.len() >= 8, "{} estimates in 1 s", on_time.len());
        assert!(on_time.iter().all(|(_, estimate)| estimate.is_some()));
        let handback = libm::roundf(OFFSET_FIT_HANDBACK_S * 2000.0) as u32;
        let interval = libm::roundf(OFFSET_FIT_SOLVE_INTERVAL_S * 2000.0) as u32;
        for pair in on_time.windows(2) {
            assert_eq!(pair[1].0 - pair[0].0, interval);
        }
        // Run in bursts of a few samples too.
        let (bursts, _) = fly(2_000, None, |tag| tag % 7 == 0);
        assert_eq!(bursts, on_time);
        // 0.1 s of samples summed one in four (2 ms), applied the hand-back after the sample
        // that completed them (the hand's 10 ms skipped first).
        assert_eq!(on_time[0].1.unwrap().samples, interval / 4);
        assert!(on_time[0].0 > interval + handback);
    }

    /// A new attempt's start drops the estimates of the one before that were not applied yet.
    #[test]
    fn a_restart_drops_the_previous_attempts_estimates_still_on_their_way() {
        let (on_time, _) = fly(2_000, None, |_| true);
        let handback = libm::roundf(OFFSET_FIT_HANDBACK_S * 2000.0) as u32;
        let solved = on_time[2].0 - handback;
        // Restarted between the third solve and its hand-back.
        let (restarted, _) = fly(2_000, Some(solved + handback / 2), |_| false);
        assert_eq!(restarted[..2], on_time[..2]);
        assert!(restarted[2].0 > on_time[2].0 + 100, "the old attempt's estimate was applied");
        assert!(restarted[2].1.unwrap().samples < on_time[2].1.unwrap().samples);
    }

    /// Attempts abandoned just after a solve leave their estimates on the way back; the client
    /// drops them as they fall due, so the estimates' ring never fills and holds the worker
    /// (and with it the client) up, however many attempts there are.
    #[test]
    fn abandoned_attempts_estimates_never_hold_the_fit_up() {
        let mut handoff = FitHandoff::new();
        let (mut client, ends) = handoff.split(2000.0);
        let mut worker = OffsetFitWorker::new(ends);
        let mut tag = 0;
        for _attempt in 0..2 * ESTIMATES_LEN {
            tag += 1;
            client.start(tag, 4, 2000.0, 0.0);
            let solved_at = worker.ends.estimates.len() + 1;
            while worker.ends.estimates.len() < solved_at {
                assert!(client.ready_for(tag + 1), "held up at sample {tag}");
                tag += 1;
                assert!(client.push(tag, sample(tag)));
                client.end_sample(tag);
                client.take_due(tag, |_| panic!("an estimate applied before its hand-back"));
                worker.run_pending();
            }
            client.stop(tag);
            // The rest of the hand-back, no work pushed: the estimate is dropped, not applied.
            let handback = libm::roundf(OFFSET_FIT_HANDBACK_S * 2000.0) as u32;
            for _ in 0..handback {
                tag += 1;
                client.end_sample(tag);
                client.take_due(tag, |_| panic!("an abandoned attempt's estimate applied"));
                worker.run_pending();
            }
            assert_eq!(worker.ends.estimates.len(), 0);
        }
    }

    /// A ring with no room for a sample's work holds the client; so does a worker that has not
    /// finished the work of the hand-back before.
    #[test]
    fn the_client_waits_for_room_and_for_the_work_it_will_apply() {
        let mut handoff = FitHandoff::new();
        let (mut client, ends) = handoff.split(2000.0);
        let mut worker = OffsetFitWorker::new(ends);
        let handback = libm::roundf(OFFSET_FIT_HANDBACK_S * 2000.0) as u32;
        client.start(1, 4, 2000.0, 0.0);
        for tag in 1..=handback {
            assert!(client.ready_for(tag), "sample {tag}");
            assert!(client.push(tag, sample(tag)));
            client.end_sample(tag);
        }
        // Sample 1's work is due with sample 1 + handback: not done yet.
        assert!(!client.ready_for(handback + 1));
        worker.run_pending();
        assert!(client.ready_for(handback + 1));
        // The ring full (nothing run): no room for a sample's work, and a push is refused.
        let mut tag = handback + 1;
        while client.push(tag, FitWork::Advance) {
            tag += 1;
        }
        assert!(!client.ready_for(tag));
        assert_eq!(worker.run_pending() as usize, FIT_WORK_LEN - 1);
        assert!(client.ready_for(tag));
    }
}
