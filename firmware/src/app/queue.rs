//! The rings out of the 2 kHz control step: learner samples to the background task, step records
//! to the link task.
//!
//! Single-producer single-consumer rings (heapless `spsc`, lock-free): the control step pushes
//! and never waits; when a ring is full the item is dropped whole and counted, so a slow consumer
//! shows up as a number (or as a gap in a telemetry topic's sequence numbers), never as a late
//! control step.

use super::hal::{ImuSample, MAX_MOTORS};
use flight::learner::FlightPhase;
use heapless::spsc::{Consumer, Producer, Queue};

/// Ring capacity, samples: 64 samples are 32 ms at 2 kHz, far longer than any background job
/// may hold the CPU. (heapless' ring keeps one slot free, so 63 are usable.) About 7.2 KB
/// (112 B a sample).
pub const SAMPLE_QUEUE_LEN: usize = 64;

/// What the control step hands to the background estimators for each IMU sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LearnerSample {
    /// Time of the control step that read the sample, µs since start-up.
    pub t_us: u64,
    pub imu: ImuSample,
    /// Motor commands δ ∈ [0, 1] set by this step.
    pub commands: [f32; MAX_MOTORS],
    /// Motor speeds reported in this step, rad/s; NaN where a motor did not report.
    pub speeds_rad_s: [f32; MAX_MOTORS],
    /// Where the throw-to-fly attempt stood in this step (the learner runs while exciting).
    pub phase: FlightPhase,
    /// Whether the craft flies on the learned model in this step (the learner keeps refining).
    pub flying: bool,
    /// Motors connected.
    pub motor_count: u8,
    /// The navigation's velocity in IMU axes, `R̂ᵀ v̂_ned` (m/s; `pilot::Pilot::velocity_imu_mps`):
    /// from the pose fixes when they come, else dead reckoning from the last rest. The in-flight
    /// IMU-offset fit's drag regressor, which takes a non-finite one as unknown.
    pub velocity_imu_mps: [f32; 3],
}

/// The ring's storage; split it once with [`SampleQueue::split`].
pub type SampleQueue = Queue<LearnerSample, SAMPLE_QUEUE_LEN>;

/// The control step's end of the learner-sample ring.
pub type SampleProducer<'q> = RingProducer<'q, LearnerSample>;
/// The background task's end of the learner-sample ring.
pub type SampleConsumer<'q> = RingConsumer<'q, LearnerSample>;

/// The producing end of a ring: pushes without blocking and counts what it drops.
pub struct RingProducer<'q, T> {
    inner: Producer<'q, T>,
    dropped: u32,
}

/// The consuming end of a ring.
pub struct RingConsumer<'q, T> {
    inner: Consumer<'q, T>,
}

/// Split a ring into its two ends (once, at start-up).
pub fn split_queue<T, const N: usize>(
    queue: &mut Queue<T, N>,
) -> (RingProducer<'_, T>, RingConsumer<'_, T>) {
    let (inner_producer, inner_consumer) = queue.split();
    (RingProducer { inner: inner_producer, dropped: 0 }, RingConsumer { inner: inner_consumer })
}

impl<T> RingProducer<'_, T> {
    /// Push an item; when the ring is full, drop it and count it. Never blocks.
    pub fn push(&mut self, item: T) {
        if self.inner.enqueue(item).is_err() {
            self.dropped = self.dropped.wrapping_add(1);
        }
    }

    /// Items dropped so far because the ring was full.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }

    /// Whether items are waiting for the consumer.
    pub fn has_waiting(&self) -> bool {
        !self.inner.is_empty()
    }
}

impl<T> RingConsumer<'_, T> {
    /// The oldest waiting item, if any.
    pub fn pop(&mut self) -> Option<T> {
        self.inner.dequeue()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_queue_drops_and_counts_instead_of_blocking() {
        let mut queue = SampleQueue::new();
        let (mut producer, mut consumer) = split_queue(&mut queue);
        let usable = SAMPLE_QUEUE_LEN - 1;
        for i in 0..usable + 10 {
            producer.push(LearnerSample { t_us: i as u64, ..Default::default() });
        }
        assert_eq!(producer.dropped(), 10);
        let received: Vec<u64> = core::iter::from_fn(|| consumer.pop()).map(|s| s.t_us).collect();
        assert_eq!(received, (0..usable as u64).collect::<Vec<_>>(), "oldest kept, in order");
    }
}
