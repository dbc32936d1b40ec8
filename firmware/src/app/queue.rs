//! The rings out of the 2 kHz control step: learner samples to the background task, step records
//! to the link task; and a one-value [`Mailbox`] for what is too large for a ring's slot.
//!
//! Single-producer single-consumer rings (heapless `spsc`, lock-free): the control step pushes
//! and never waits; when a ring is full the item is dropped whole and counted, so a slow consumer
//! shows up as a number (or as a gap in a telemetry topic's sequence numbers), never as a late
//! control step.

use super::hal::{ImuSample, MAX_MOTORS};
use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicU8, Ordering};
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
    accepted: u32,
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
    (
        RingProducer { inner: inner_producer, dropped: 0, accepted: 0 },
        RingConsumer { inner: inner_consumer },
    )
}

impl<T> RingProducer<'_, T> {
    /// Push an item; when the ring is full, drop it and count it. Never blocks.
    pub fn push(&mut self, item: T) {
        if self.inner.enqueue(item).is_err() {
            self.dropped = self.dropped.wrapping_add(1);
        } else {
            self.accepted = self.accepted.wrapping_add(1);
        }
    }

    /// Items dropped so far because the ring was full.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }

    /// Items the ring took so far (each reaches the consumer, in order): how many the consumer
    /// will have popped before the next one pushed.
    pub fn accepted(&self) -> u32 {
        self.accepted
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

    /// Whether items wait.
    pub fn has_waiting(&self) -> bool {
        self.inner.ready()
    }
}

/// One value handed from a task to a lower-priority one, too large for a ring's slot (the
/// control loop's state at an arming, 9 KB, for the flight log): the producer copies it in
/// place without waiting, the consumer reads it in place, then frees the box.
///
/// Lock-free with one producer and one consumer: a state byte says who owns the value. The
/// producer writes only into an empty box (a full one keeps the older value until it is read:
/// the consumer, working through its ring in order, wants the oldest first); the consumer reads
/// only a full one. On the board the producer is the highest-priority task, so it can never be
/// interrupted by the consumer; on the host they may be two threads, which the states keep apart.
pub struct Mailbox<H, T> {
    value: UnsafeCell<MaybeUninit<(H, T)>>,
    state: AtomicU8,
}

const MAILBOX_EMPTY: u8 = 0;
const MAILBOX_WRITING: u8 = 1;
const MAILBOX_FULL: u8 = 2;
const MAILBOX_READING: u8 = 3;

// SAFETY: the value is reached only by the end that owns it by `state` (acquired and released
// with it), one producer and one consumer (the ends are created once by `split`).
unsafe impl<H: Send, T: Send> Sync for Mailbox<H, T> {}

impl<H: Copy, T: Copy> Default for Mailbox<H, T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<H: Copy, T: Copy> Mailbox<H, T> {
    /// An empty box (no value is ever read before one was put in).
    pub const fn new() -> Self {
        Self { value: UnsafeCell::new(MaybeUninit::uninit()), state: AtomicU8::new(MAILBOX_EMPTY) }
    }

    /// An empty box written in place (only its state: the value needs no initialisation), for
    /// a box in a static that start-up code does not initialise.
    ///
    /// # Safety
    /// `this` must be valid for writes and aligned.
    pub unsafe fn init_in(this: *mut Self) {
        core::ptr::addr_of_mut!((*this).state).write(AtomicU8::new(MAILBOX_EMPTY));
    }

    /// The two ends (once, at start-up).
    pub fn split(&mut self) -> (MailboxProducer<'_, H, T>, MailboxConsumer<'_, H, T>) {
        let shared: &Self = self;
        (MailboxProducer { mailbox: shared }, MailboxConsumer { mailbox: shared })
    }
}

/// The writing end of a [`Mailbox`].
pub struct MailboxProducer<'q, H, T> {
    mailbox: &'q Mailbox<H, T>,
}

/// The reading end of a [`Mailbox`].
pub struct MailboxConsumer<'q, H, T> {
    mailbox: &'q Mailbox<H, T>,
}

impl<H: Copy, T: Copy> MailboxProducer<'_, H, T> {
    /// Copy `value`, with its `header`, into the box if it is empty; false (nothing written) if
    /// it still holds a value or is being read. Never blocks; one copy, in place.
    pub fn put(&mut self, header: H, value: &T) -> bool {
        let mailbox = self.mailbox;
        if mailbox
            .state
            .compare_exchange(MAILBOX_EMPTY, MAILBOX_WRITING, Ordering::Acquire, Ordering::Relaxed)
            .is_err()
        {
            return false;
        }
        // SAFETY: WRITING gives this end the value alone until it stores FULL; `value` is `Copy`
        // and cannot overlap the box (the box is reached only through the two ends).
        unsafe {
            let slot = (*mailbox.value.get()).as_mut_ptr();
            core::ptr::addr_of_mut!((*slot).0).write(header);
            core::ptr::copy_nonoverlapping(value, core::ptr::addr_of_mut!((*slot).1), 1);
        }
        mailbox.state.store(MAILBOX_FULL, Ordering::Release);
        true
    }
}

impl<H: Copy, T: Copy> MailboxConsumer<'_, H, T> {
    /// The header of the value waiting, if one is.
    pub fn waiting(&self) -> Option<H> {
        self.read(|header, _| header)
    }

    /// Read the waiting value in place with `f` (its header and the value), then empty the box;
    /// `None` (and `f` not called) if it is empty.
    pub fn take<R>(&mut self, f: impl FnOnce(H, &T) -> R) -> Option<R> {
        let result = self.read(f)?;
        self.mailbox.state.store(MAILBOX_EMPTY, Ordering::Release);
        Some(result)
    }

    fn read<R>(&self, f: impl FnOnce(H, &T) -> R) -> Option<R> {
        let mailbox = self.mailbox;
        mailbox
            .state
            .compare_exchange(MAILBOX_FULL, MAILBOX_READING, Ordering::Acquire, Ordering::Relaxed)
            .ok()?;
        // SAFETY: READING gives this end the value alone (the producer writes only into an
        // empty box); FULL means it was written whole.
        let result = unsafe {
            let slot = &*(*mailbox.value.get()).as_ptr();
            f(slot.0, &slot.1)
        };
        mailbox.state.store(MAILBOX_FULL, Ordering::Release);
        Some(result)
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

    #[test]
    fn a_mailbox_keeps_the_oldest_value_until_it_is_taken() {
        let mut mailbox = Mailbox::<u32, [f32; 1000]>::new();
        let (mut producer, mut consumer) = mailbox.split();
        assert_eq!(consumer.take(|tag, _| tag), None, "empty at first");
        assert!(producer.put(7, &[1.5; 1000]));
        assert!(!producer.put(8, &[2.5; 1000]), "a full box refuses a newer value");
        assert_eq!(consumer.waiting(), Some(7), "looking does not empty it");
        assert_eq!(consumer.take(|tag, value| (tag, value[999])), Some((7, 1.5)));
        assert_eq!(consumer.waiting(), None, "taken");
        assert!(producer.put(8, &[2.5; 1000]), "empty again: the next value goes in");
        assert_eq!(consumer.take(|tag, value| (tag, value[0])), Some((8, 2.5)));
    }

    #[test]
    fn a_ring_counts_what_it_accepted_apart_from_what_it_dropped() {
        let mut queue = SampleQueue::new();
        let (mut producer, mut consumer) = split_queue(&mut queue);
        for _ in 0..SAMPLE_QUEUE_LEN + 5 {
            producer.push(LearnerSample::default());
        }
        assert_eq!(producer.accepted(), (SAMPLE_QUEUE_LEN - 1) as u32);
        assert_eq!(producer.dropped(), 6);
        consumer.pop();
        producer.push(LearnerSample::default());
        assert_eq!(producer.accepted(), SAMPLE_QUEUE_LEN as u32, "room again after a pop");
    }
}
