//! Pairing colour and depth frames by timestamp.
//!
//! Colour and depth arrive on separate V4L2 nodes, each with its own
//! timestamps and its own drops. [`FramePairer`] keeps a few frames of each
//! stream and emits a pair when a colour and a depth frame are within the
//! tolerance of each other and neither has a closer partner already queued.
//! Frames that can no longer be paired (their partner was dropped, or a queue
//! overflowed) are discarded and counted.

use std::collections::VecDeque;

/// Default pairing tolerance: half a frame period at 30 fps, less a margin.
pub const DEFAULT_PAIR_TOLERANCE_S: f64 = 0.015;
/// Default number of unpaired frames kept per stream.
pub const DEFAULT_PAIR_QUEUE: usize = 8;

/// A frame with its capture time.
#[derive(Clone, Debug, PartialEq)]
pub struct Timed<T> {
    /// Capture time in seconds (one clock for both streams).
    pub timestamp_s: f64,
    /// The payload (an image, a raw buffer).
    pub value: T,
}

/// A colour frame and the depth frame paired with it.
#[derive(Clone, Debug, PartialEq)]
pub struct Pair<C, D> {
    /// The colour frame.
    pub color: Timed<C>,
    /// The depth frame.
    pub depth: Timed<D>,
}

impl<C, D> Pair<C, D> {
    /// Depth time minus colour time, seconds.
    pub fn skew_s(&self) -> f64 {
        self.depth.timestamp_s - self.color.timestamp_s
    }
}

/// What a [`FramePairer`] has done so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PairingStats {
    /// Pairs emitted.
    pub paired: u64,
    /// Colour frames discarded without a partner.
    pub dropped_color: u64,
    /// Depth frames discarded without a partner.
    pub dropped_depth: u64,
}

/// Pairs two timestamped streams (see the module docs).
#[derive(Debug)]
pub struct FramePairer<C, D> {
    tolerance_s: f64,
    capacity: usize,
    color: VecDeque<Timed<C>>,
    depth: VecDeque<Timed<D>>,
    stats: PairingStats,
}

impl<C, D> FramePairer<C, D> {
    /// A pairer accepting |depth time - colour time| <= `tolerance_s`, keeping
    /// at most `capacity` (>= 1) unpaired frames per stream.
    pub fn new(tolerance_s: f64, capacity: usize) -> FramePairer<C, D> {
        FramePairer {
            tolerance_s: tolerance_s.max(0.0),
            capacity: capacity.max(1),
            color: VecDeque::new(),
            depth: VecDeque::new(),
            stats: PairingStats::default(),
        }
    }

    /// Counts so far.
    pub fn stats(&self) -> PairingStats {
        self.stats
    }

    /// Adds a colour frame. Frames of one stream must come in time order; an
    /// older frame than the last one is discarded (counted).
    pub fn push_color(&mut self, frame: Timed<C>) {
        push_bounded(&mut self.color, frame, self.capacity, &mut self.stats.dropped_color);
    }

    /// Adds a depth frame (same rules as [`push_color`](Self::push_color)).
    pub fn push_depth(&mut self, frame: Timed<D>) {
        push_bounded(&mut self.depth, frame, self.capacity, &mut self.stats.dropped_depth);
    }

    /// The next pair, if one can be decided from what is queued. Call it after
    /// every push until it returns `None`.
    pub fn pop_pair(&mut self) -> Option<Pair<C, D>> {
        loop {
            let tc = self.color.front()?.timestamp_s;
            let td = self.depth.front()?.timestamp_s;
            // A depth frame older than the oldest colour by more than the
            // tolerance can pair with nothing that is queued or still to come.
            if td < tc - self.tolerance_s {
                self.depth.pop_front();
                self.stats.dropped_depth += 1;
                continue;
            }
            if tc < td - self.tolerance_s {
                self.color.pop_front();
                self.stats.dropped_color += 1;
                continue;
            }
            // Within tolerance: prefer a closer partner that is already queued.
            if let Some(d2) = self.depth.get(1)
                && (d2.timestamp_s - tc).abs() < (td - tc).abs()
            {
                self.depth.pop_front();
                self.stats.dropped_depth += 1;
                continue;
            }
            if let Some(c2) = self.color.get(1)
                && (c2.timestamp_s - td).abs() < (tc - td).abs()
            {
                self.color.pop_front();
                self.stats.dropped_color += 1;
                continue;
            }
            let (color, depth) = (self.color.pop_front()?, self.depth.pop_front()?);
            self.stats.paired += 1;
            return Some(Pair { color, depth });
        }
    }

    /// Discards everything queued (counted as dropped), e.g. after a device reopened.
    pub fn clear(&mut self) {
        self.stats.dropped_color += self.color.len() as u64;
        self.stats.dropped_depth += self.depth.len() as u64;
        self.color.clear();
        self.depth.clear();
    }
}

/// Appends `frame` unless it is older than the newest queued one; keeps at most
/// `capacity` frames by dropping the oldest. Every discarded frame adds to `dropped`.
fn push_bounded<T>(queue: &mut VecDeque<Timed<T>>, frame: Timed<T>, capacity: usize, dropped: &mut u64) {
    if queue.back().is_some_and(|b| frame.timestamp_s < b.timestamp_s) {
        *dropped += 1;
        return;
    }
    queue.push_back(frame);
    if queue.len() > capacity {
        queue.pop_front();
        *dropped += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t<T>(timestamp_s: f64, value: T) -> Timed<T> {
        Timed { timestamp_s, value }
    }

    #[test]
    fn pairs_the_nearest_and_counts_the_rest() {
        let mut p = FramePairer::new(0.010, 8);
        p.push_color(t(0.000, 0));
        p.push_depth(t(0.004, 0));
        assert_eq!(p.pop_pair().map(|x| (x.color.value, x.depth.value)), Some((0, 0)));
        // Depth 1 lost; colour 1 must not pair with depth 2 (33 ms away).
        p.push_color(t(0.033, 1));
        p.push_color(t(0.066, 2));
        p.push_depth(t(0.070, 2));
        assert_eq!(p.pop_pair().map(|x| (x.color.value, x.depth.value)), Some((2, 2)));
        assert_eq!(p.pop_pair(), None);
        assert_eq!(p.stats(), PairingStats { paired: 2, dropped_color: 1, dropped_depth: 0 });
    }

    #[test]
    fn a_closer_queued_partner_wins() {
        let mut p = FramePairer::new(0.020, 8);
        p.push_depth(t(0.000, 'a'));
        p.push_depth(t(0.012, 'b'));
        p.push_color(t(0.010, 'x'));
        let pair = p.pop_pair().expect("a pair");
        assert_eq!((pair.color.value, pair.depth.value), ('x', 'b'));
        assert!((pair.skew_s() - 0.002).abs() < 1e-12);
        assert_eq!(p.stats().dropped_depth, 1);
    }

    #[test]
    fn queues_are_bounded_and_out_of_order_frames_dropped() {
        let mut p: FramePairer<u32, u32> = FramePairer::new(0.010, 3);
        for i in 0..10 {
            p.push_color(t(f64::from(i), i));
        }
        p.push_color(t(1.0, 99));
        assert_eq!(p.stats().dropped_color, 8);
        assert_eq!(p.pop_pair(), None);
        p.clear();
        assert_eq!(p.stats().dropped_color, 11);
    }
}
