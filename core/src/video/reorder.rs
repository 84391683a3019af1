//! Puts decoded pictures in presentation order.
//!
//! Samples are decoded in decode order; with B-frames a picture comes out after later
//! samples were fed. Every fed sample is registered with its presentation key; a decoded
//! picture is released once it is the earliest key still outstanding. A sample that never
//! yields a picture (corrupt data) would block the queue, so when more pictures wait than
//! any H.264 stream can hold back (16 reference frames), the earliest one is released anyway
//! and the samples skipped over are reported as lost.

use std::collections::{BTreeMap, BTreeSet};

/// Presentation order key: presentation time, then decode index for equal times.
pub(crate) type Key = (i64, u64);

/// Most pictures kept waiting: the H.264 DPB holds at most 16 frames.
const MAX_WAITING: usize = 17;

pub(crate) struct Reorder<T> {
    outstanding: BTreeSet<Key>,
    ready: BTreeMap<Key, T>,
}

/// What `pop` hands back.
pub(crate) struct Released<T> {
    pub key: Key,
    pub item: T,
    /// Samples presented before this one that never produced a picture.
    pub lost: Vec<Key>,
}

impl<T> Reorder<T> {
    pub fn new() -> Self {
        Self {
            outstanding: BTreeSet::new(),
            ready: BTreeMap::new(),
        }
    }

    /// A sample was fed to the decoder.
    pub fn fed(&mut self, key: Key) {
        self.outstanding.insert(key);
    }

    /// A picture came out for `key`. Pictures for keys never fed (a corrupt token) or
    /// already released are dropped.
    pub fn decoded(&mut self, key: Key, item: T) {
        if self.outstanding.contains(&key) {
            self.ready.insert(key, item);
        }
    }

    /// The next picture in presentation order, if it may be released now. With `end`
    /// (the decoder is drained), everything ready is released.
    pub fn pop(&mut self, end: bool) -> Option<Released<T>> {
        let first_ready = *self.ready.keys().next()?;
        let first_outstanding = self.outstanding.first().copied();
        if !end && first_outstanding != Some(first_ready) && self.ready.len() <= MAX_WAITING {
            return None;
        }
        let item = self.ready.remove(&first_ready)?;
        let mut lost = Vec::new();
        while let Some(k) = self.outstanding.pop_first() {
            if k == first_ready {
                break;
            }
            lost.push(k);
        }
        Some(Released {
            key: first_ready,
            item,
            lost,
        })
    }

    /// Keys that were fed and never released (call after the last `pop(true)`).
    pub fn take_outstanding(&mut self) -> Vec<Key> {
        std::mem::take(&mut self.outstanding).into_iter().collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn releases_in_presentation_order_and_reports_lost() {
        let mut r = Reorder::new();
        // Decode order I0 P3 B1 B2 with presentation times 0 3 1 2.
        for (pts, i) in [(0, 0), (3, 1), (1, 2), (2, 3)] {
            r.fed((pts, i));
        }
        r.decoded((3, 1), "P");
        assert!(r.pop(false).is_none());
        r.decoded((0, 0), "I");
        assert_eq!(r.pop(false).map(|x| x.item), Some("I"));
        assert!(r.pop(false).is_none());
        // B1 is lost; B2 arrives, then the end releases everything in order.
        r.decoded((2, 3), "B2");
        assert!(r.pop(false).is_none());
        let b2 = r.pop(true).unwrap();
        assert_eq!((b2.item, b2.lost), ("B2", vec![(1, 2)]));
        assert_eq!(r.pop(true).map(|x| x.item), Some("P"));
        assert!(r.pop(true).is_none());
        assert!(r.take_outstanding().is_empty());
    }
}
