//! Whether the tracks tie every frame's exposure to the others.
//!
//! An exposure is known only relative to frames that share a measured scene point with it
//! (directly or through other frames). When the tracks break off completely, for instance when
//! a bright exposure step clips most of the frame and the tracker loses every point, the video
//! falls into parts whose exposures have no common scale: any factor between the parts explains
//! the samples equally well, and the fit returns one of them. On a held-out sweep sequence of
//! `examples/photometric_sweep.rs` (`eval2#7`: 66 % of the pixels clipped, one-stop exposure
//! steps) the tracks broke at frame 144 and the exposures after it came out 12× off
//! (exposure error 97 %) while the response and vignetting were still right. So the fit refuses
//! such a video and names the parts, instead of returning numbers the data do not determine.
//!
//! Clipped samples are left out of the links on purpose: a bound says only that a point was at
//! least (or at most) so bright, so across a break it limits the factor between the parts to an
//! interval. On `eval#1` (a linear camera under steps, tracks broken at frame 35) that interval
//! happened to be narrow and the exposures came out 2.4 % off; on `eval2#7` it was not. Telling
//! the two apart would need the width of that interval; until then both are refused by
//! default.
//!
//! The response and vignetting do not need the link: every part constrains them on its own.
//! `broken_tracks: per_part` therefore fits all parts together, each with its own free
//! exposure scale, and reports each part's exposures relative to its own first frame with the
//! part of every frame (`exposure_parts`), which is what a user who only needs DSO's
//! `pcalib.txt` and `vignette.png` from a video with a cut or a blown-out stretch wants.

use super::super::joint::Obs;
use crate::error::{CoreError, CoreResult};
use crate::union_find::root;

/// Connected parts of the frame graph (frames joined by a scene point measured in both), each
/// as its sorted frame indices; frames without any measured sample are parts of their own.
/// `obs` must be sorted by point (as [`super::Observations`] is).
pub(super) fn frame_parts(obs: &[Obs], frames: usize) -> Vec<Vec<usize>> {
    let mut parent: Vec<usize> = (0..frames).collect();
    let mut last: Option<(u32, usize)> = None;
    for o in obs.iter().filter(|o| o.measured()) {
        let f = o.frame as usize;
        if f >= frames {
            continue;
        }
        if let Some((p, g)) = last
            && p == o.point
        {
            let (a, b) = (root(&mut parent, g), root(&mut parent, f));
            parent[a.max(b)] = a.min(b);
        }
        last = Some((o.point, f));
    }
    let mut parts: Vec<Vec<usize>> = Vec::new();
    let mut index = vec![usize::MAX; frames];
    for f in 0..frames {
        let r = root(&mut parent, f);
        if index[r] == usize::MAX {
            index[r] = parts.len();
            parts.push(Vec::new());
        }
        parts[index[r]].push(f);
    }
    parts
}

/// The parts of [`frame_parts`] that hold a measured sample, in order of their first frame.
fn sampled_parts(obs: &[Obs], frames: usize) -> Vec<Vec<usize>> {
    let mut sampled = vec![false; frames];
    for o in obs.iter().filter(|o| o.measured()) {
        if let Some(s) = sampled.get_mut(o.frame as usize) {
            *s = true;
        }
    }
    frame_parts(obs, frames)
        .into_iter()
        .filter(|p| p.iter().any(|&f| sampled[f]))
        .collect()
}

/// With more than one part (`broken_tracks: per_part`): the part of every frame, as an index
/// into the sampled parts in order of their first frame. A frame without a measured sample
/// belongs to the part of the nearest earlier frame that has one (the first part for leading
/// frames): its exposure is fitted from its censored bounds and its neighbours', as in a
/// linked video. `None` when the video is one part.
pub(super) fn part_labels(obs: &[Obs], frames: usize) -> Option<Vec<usize>> {
    let parts = sampled_parts(obs, frames);
    if parts.len() <= 1 {
        return None;
    }
    let mut label = vec![usize::MAX; frames];
    for (i, p) in parts.iter().enumerate() {
        for &f in p {
            label[f] = i;
        }
    }
    let mut last = 0;
    for l in &mut label {
        if *l == usize::MAX {
            *l = last;
        } else {
            last = *l;
        }
    }
    Some(label)
}

/// Divide each part's exposures by the exposure of the part's first frame, so that every
/// ratio is relative to a frame it shares a scale with (part 0 starts at frame 0, which the
/// fit holds at 1).
pub(super) fn normalise_parts(exposures: &mut [f64], labels: &[usize]) {
    let parts = labels.iter().copied().max().map_or(0, |m| m + 1);
    let mut first: Vec<Option<f64>> = vec![None; parts];
    for (e, &l) in exposures.iter().zip(labels) {
        first[l].get_or_insert(*e);
    }
    for (e, &l) in exposures.iter_mut().zip(labels) {
        if let Some(f) = first[l].filter(|f| *f > 0.0) {
            *e /= f;
        }
    }
}

/// `Ok` when every frame with a measured sample is tied to every other such frame; otherwise
/// an input error that names the parts (as frame ranges, 0-based) and what to do.
///
/// Frames without any measured sample (all black or all clipped, such as a camera's first
/// frames while its auto-exposure settles) do not make a video fail: their exposures follow
/// their neighbours' and the censored bounds, as before; refusing a whole video for them would
/// be worse than the exposure of one unusable frame.
pub(super) fn require_linked(obs: &[Obs], frames: usize) -> CoreResult<()> {
    let parts = sampled_parts(obs, frames);
    if parts.len() <= 1 {
        return Ok(());
    }
    const SHOWN: usize = 6;
    let mut names: Vec<String> = parts.iter().take(SHOWN).map(|p| ranges(p)).collect();
    if parts.len() > SHOWN {
        names.push(format!("{} more", parts.len() - SHOWN));
    }
    Err(CoreError::input(format!(
        "the tracks do not tie all frames' exposures together: the video falls into {} parts \
         that share no measured scene point (frames {}, from 0 in the order fitted), so \
         their exposures have no common scale; this happens when most of a frame is clipped \
         or the view jumps. Submit the frames of one part or a video with less clipping, or set \
         `broken_tracks: per_part` to fit the response and vignetting from all parts with \
         each part's exposures relative to its own first frame",
        parts.len(),
        names.join("; ")
    )))
}

/// `0-143, 150` style ranges of sorted frame indices.
fn ranges(frames: &[usize]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < frames.len() {
        let mut j = i;
        while j + 1 < frames.len() && frames[j + 1] == frames[j] + 1 {
            j += 1;
        }
        out.push(if i == j {
            frames[i].to_string()
        } else {
            format!("{}-{}", frames[i], frames[j])
        });
        i = j + 1;
    }
    out.join(", ")
}

#[cfg(test)]
mod tests {
    use super::{frame_parts, ranges, require_linked};
    use crate::photometric::joint::{Censor, Obs};

    fn obs(point: u32, frame: u32, censor: Censor) -> Obs {
        Obs {
            point,
            frame,
            r2: 0.0,
            value: 0.5,
            weight: 1.0,
            censor,
        }
    }

    /// Points 0–1 join frames 0–2, point 2 joins 3–4 only: two parts, named as ranges.
    /// A censored sample does not link (it only bounds the prediction).
    #[test]
    fn a_break_in_the_tracks_splits_the_frames() {
        let mut o = vec![
            obs(0, 0, Censor::Exact),
            obs(0, 1, Censor::Exact),
            obs(1, 1, Censor::Exact),
            obs(1, 2, Censor::Exact),
            obs(1, 3, Censor::AtLeast),
            obs(2, 3, Censor::Exact),
            obs(2, 4, Censor::Exact),
        ];
        assert_eq!(frame_parts(&o, 5), vec![vec![0, 1, 2], vec![3, 4]]);
        let err = require_linked(&o, 5).expect_err("two parts").to_string();
        assert!(err.contains("2 parts") && err.contains("0-2; 3-4"), "{err}");
        // One exact sample of point 1 in frame 3 bridges the gap.
        o[4].censor = Censor::Exact;
        assert_eq!(frame_parts(&o, 5).len(), 1);
        assert!(require_linked(&o, 5).is_ok());
    }

    /// A frame without any measured sample (all clipped) is a part of its own, but does not
    /// make the video fail; a frame whose samples link to nothing does.
    #[test]
    fn a_frame_without_samples_is_its_own_part() {
        let mut o = vec![
            obs(0, 0, Censor::Exact),
            obs(0, 1, Censor::Exact),
            obs(0, 3, Censor::Exact),
            obs(1, 2, Censor::AtLeast),
        ];
        assert_eq!(frame_parts(&o, 4), vec![vec![0, 1, 3], vec![2]]);
        assert!(require_linked(&o, 4).is_ok());
        o.push(obs(2, 2, Censor::Exact));
        let err = require_linked(&o, 4)
            .expect_err("frame 2 unlinked")
            .to_string();
        assert!(err.contains("0-1, 3; 2"), "{err}");
        assert_eq!(ranges(&[0, 1, 3, 5, 6, 7]), "0-1, 3, 5-7");
    }
}
