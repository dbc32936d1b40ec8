//! The batch estimator for recorded logs (the seed paper fitted offline): the same detection,
//! trimming, front end and rows as the board, accumulated in `f64`, over one or more logs.
//!
//! Each log is read twice. Pass 1 runs the onboard [`ImuOffsetEstimator`] to find the segments
//! (so the board and the host always agree on which samples count). Pass 2 replays the front end
//! and accumulates exactly those samples, block by block, in `f64`. No allocation: the caller owns
//! the samples; the segments are kept in a fixed array.

use nalgebra::Vector3;

use super::drag::{DragSums, DragThrow};
use super::front_end::FrontEnd;
use super::moments::{BatchMeans, Moments};
use super::rest::RestPoses;
use super::solve::{self, Problem};
use super::stream::{aligned_row, ImuOffsetEstimator};
use super::{
    validate_sample, Config, DragModel, Estimate, ImuOffsetError, ImuSample, Segment, MAX_SEGMENTS,
};

/// A segment of one of the logs given to [`BatchFitter::add_log`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogSegment {
    /// Which log (0 for the first `add_log` call, counting every call).
    pub log: u32,
    /// Sample indices within that log.
    pub segment: Segment,
}

/// Least squares over the free-fall segments of any number of logs at one sample rate.
#[derive(Debug, Clone)]
pub struct BatchFitter {
    config: Config,
    rate_hz: Option<f32>,
    block_len: u32,
    rows: Moments<f64>,
    batches: Option<BatchMeans<f64>>,
    /// The drag-extended sums, with [`DragModel::VerticalQuadratic`].
    drag: Option<DragSums>,
    /// Rest poses of all logs, as the onboard detector found them.
    rest: RestPoses,
    logs_added: u32,
    segments: [LogSegment; MAX_SEGMENTS],
    segments_len: usize,
}

impl BatchFitter {
    /// An empty fit.
    pub fn new(config: Config) -> Self {
        let none = LogSegment { log: 0, segment: Segment { start_index: 0, end_index: 0 } };
        Self {
            config,
            rate_hz: None,
            block_len: 0,
            rows: Moments::new(),
            batches: None,
            drag: None,
            rest: RestPoses::new(),
            logs_added: 0,
            segments: [none; MAX_SEGMENTS],
            segments_len: 0,
        }
    }

    /// Find the throws in one log sampled at `rate_hz` and add their samples to the fit; returns
    /// the number of throws used (possibly 0; at most [`MAX_SEGMENTS`] over all logs, later
    /// throws are ignored). Logs must share one rate. A non-finite or corrupt sample rejects the
    /// whole log (nothing is added).
    pub fn add_log(
        &mut self,
        samples: &[ImuSample],
        rate_hz: f32,
    ) -> Result<usize, ImuOffsetError> {
        if let Some(expected_hz) = self.rate_hz {
            if expected_hz != rate_hz {
                return Err(ImuOffsetError::RateMismatch { expected_hz, found_hz: rate_hz });
            }
        }
        let mut detector = ImuOffsetEstimator::new(rate_hz, self.config)?;
        let required = detector.min_free_fall_len();
        let used = u32::try_from(samples.len()).unwrap_or(u32::MAX);
        if used < required {
            return Err(ImuOffsetError::TooFewSamples { used, required });
        }
        for (index, sample) in (0u32..).zip(samples.iter()) {
            validate_sample(sample, index)?;
        }
        for sample in samples {
            detector.update(sample)?;
        }
        detector.finish();
        self.rest.extend(detector.rest_pose_list());
        // Only as many throws as the segment list can still name are used, so every sample in
        // the fit belongs to a reported segment.
        let room = MAX_SEGMENTS.saturating_sub(self.segments_len);
        let found = detector.segments().get(..room).unwrap_or(detector.segments());
        let block_len = detector.block_len();
        let group = detector.long_batch_blocks();
        let batches = self.batches.get_or_insert(BatchMeans::new(group));
        let mut drag = match self.config.drag_model {
            DragModel::Ignored => None,
            DragModel::VerticalQuadratic => Some(self.drag.get_or_insert(DragSums::new())),
        };

        // Pass 2: the same front end, accumulating exactly the detected segments in f64, block
        // by block as the board commits them.
        let mut front = FrontEnd::new(self.config.cutoff_hz, rate_hz)
            .map_err(|_| ImuOffsetError::InvalidConfig("cutoff_hz must be in (0, rate/4]"))?;
        let r_ref = Vector3::zeros();
        let mut block = Moments::<f64>::new();
        let mut segment_rows = Moments::<f64>::new();
        let mut throw = DragThrow::<f64>::new(rate_hz);
        let mut next = found.iter().peekable();
        let mut open = false;
        for sample in samples {
            let Some(s) = front.update(sample) else { continue };
            while let Some(seg) = next.next_if(|seg| s.index >= seg.end_index) {
                if open {
                    batches.end_segment();
                    if let Some(d) = drag.as_deref_mut() {
                        d.add_throw(&throw, &segment_rows, seg, block_len, group, rate_hz);
                    }
                    open = false;
                }
            }
            let Some(_) = next.peek().filter(|seg| s.index >= seg.start_index) else {
                continue;
            };
            if !open {
                (block, segment_rows, open) = (Moments::new(), Moments::new(), true);
                throw.begin();
            }
            let (x, y, w) = aligned_row(&s, &r_ref);
            block.accumulate(&x, &y);
            let modelled = drag.is_some();
            if modelled {
                throw.add_row(&x, &y, &w);
            }
            if block.count >= block_len {
                self.rows.merge(&block);
                segment_rows.merge(&block);
                batches.add_block(&block);
                if modelled {
                    let drag_sums = throw.take_block();
                    throw.commit(&block.xsum, &block.ysum, drag_sums);
                }
                block = Moments::new();
            }
        }
        if let Some(seg) = next.next().filter(|_| open) {
            batches.end_segment();
            if let Some(d) = drag {
                d.add_throw(&throw, &segment_rows, seg, block_len, group, rate_hz);
            }
        }
        let log = self.logs_added;
        self.logs_added = self.logs_added.saturating_add(1);
        self.rate_hz = Some(rate_hz);
        self.block_len = block_len;
        for segment in found {
            if let Some(slot) = self.segments.get_mut(self.segments_len) {
                *slot = LogSegment { log, segment: *segment };
                self.segments_len += 1;
            }
        }
        Ok(found.len())
    }

    /// The throws used, in the order found.
    pub fn segments(&self) -> &[LogSegment] {
        self.segments.get(..self.segments_len).unwrap_or(&[])
    }

    /// Rest poses found in the logs.
    pub fn rest_poses(&self) -> u32 {
        self.rest.as_slice().len() as u32
    }

    /// Samples (rows of eq. 3) in the fit.
    pub fn samples_used(&self) -> u32 {
        self.rows.count
    }

    /// The estimate over all throws added.
    pub fn estimate(&self) -> Result<Estimate<f64>, ImuOffsetError> {
        let Some(batches) = self.batches.as_ref().filter(|_| self.segments_len > 0) else {
            return Err(ImuOffsetError::NoFreeFall);
        };
        let problem = Problem {
            rows: &self.rows,
            batches,
            block_len: self.block_len,
            r_ref: Vector3::zeros(),
            drag: self.drag.as_ref(),
            rest: Some(self.rest.model(&self.config)),
        };
        solve::estimate(&problem, &self.config)
    }
}
