//! Decoding is sequential; what is done with the frames (scoring, board detection) costs more
//! and parallelises. [`overlap_batches`] lets the decoding loop hand batches of frames to the
//! rayon pool and go on decoding, with a bound on the batches in flight so that memory stays
//! bounded whatever the clip's length.

use std::sync::atomic::{AtomicUsize, Ordering::SeqCst};

/// Runs `produce` on the calling thread with a hand-off function: each batch handed off is
/// processed by `work` in the background on the rayon pool, or on the calling thread itself
/// while `max_in_flight` batches are already being processed (which also lends the pool a
/// hand). Returns when `produce` has returned and every batch has been processed.
pub(crate) fn overlap_batches<B: Send, R>(
    max_in_flight: usize,
    work: impl Fn(B) + Sync,
    produce: impl FnOnce(&dyn Fn(B)) -> R,
) -> R {
    let in_flight = AtomicUsize::new(0);
    let (work, in_flight) = (&work, &in_flight);
    rayon::in_place_scope(|scope| {
        let hand_off = |batch: B| {
            if in_flight.fetch_add(1, SeqCst) < max_in_flight {
                scope.spawn(move |_| {
                    work(batch);
                    in_flight.fetch_sub(1, SeqCst);
                });
            } else {
                work(batch);
                in_flight.fetch_sub(1, SeqCst);
            }
        };
        produce(&hand_off)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[test]
    fn every_batch_is_processed_once() {
        let seen = Mutex::new(Vec::new());
        let n = overlap_batches(
            2,
            |b: Vec<u32>| seen.lock().unwrap().extend(b),
            |hand_off| {
                for k in 0..50u32 {
                    hand_off(vec![2 * k, 2 * k + 1]);
                }
                50
            },
        );
        let mut v = seen.into_inner().unwrap();
        v.sort_unstable();
        assert_eq!((n, v), (50, (0..100).collect::<Vec<_>>()));
    }
}
