//! How the images of a rig dataset become frames: grouped by camera folder, then matched
//! across cameras by natural order or by a timestamp in the file names.

use std::collections::BTreeMap;

use super::super::photometric::natural_cmp;
use super::{RigCalibParams, permanent};
use crate::jobs::{JobError, JobInput};

/// One image of one camera.
pub(super) struct Shot {
    pub camera: usize,
    pub name: String,
    pub file: usize,
}

/// Camera folder names (in the order used) and the images of each, in natural order.
pub(super) fn group(
    input: &JobInput,
    p: &RigCalibParams,
) -> Result<(Vec<String>, Vec<Shot>), JobError> {
    let mut folders: BTreeMap<String, Vec<(String, usize)>> = BTreeMap::new();
    for (k, f) in input.files.iter().enumerate() {
        let Some((dir, file)) = f.name.rsplit_once('/') else {
            return Err(permanent(
                "invalid_input",
                format!(
                    "{:?} is not in a camera folder: a rig dataset holds one folder per camera (cam0/…, cam1/…), e.g. a zip of those folders",
                    f.name
                ),
            ));
        };
        let camera = dir.rsplit('/').next().unwrap_or(dir).to_string();
        folders
            .entry(camera)
            .or_default()
            .push((file.to_string(), k));
    }
    let mut names: Vec<String> = folders.keys().cloned().collect();
    names.sort_by(|a, b| natural_cmp(a, b));
    if let Some(chosen) = &p.cameras {
        if let Some(missing) = chosen.iter().find(|c| !folders.contains_key(*c)) {
            return Err(permanent(
                "invalid_param",
                format!(
                    "params.cameras names {missing:?}, but the dataset's camera folders are {names:?}"
                ),
            ));
        }
        names = chosen.clone();
    }
    if names.len() < 2 {
        return Err(permanent(
            "invalid_input",
            format!("a rig needs at least 2 camera folders, the dataset has {names:?}"),
        ));
    }
    if names.len() > caliper_core::rig::MAX_CAMERAS {
        return Err(permanent(
            "invalid_input",
            format!(
                "{} camera folders; at most {}",
                names.len(),
                caliper_core::rig::MAX_CAMERAS
            ),
        ));
    }
    let mut shots = Vec::new();
    for (c, n) in names.iter().enumerate() {
        let mut files = folders.remove(n).unwrap_or_default();
        files.sort_by(|a, b| natural_cmp(&a.0, &b.0));
        shots.extend(files.into_iter().map(|(_, file)| Shot {
            camera: c,
            name: input.files[file].name.clone(),
            file,
        }));
    }
    Ok((names, shots))
}

/// Frame rows (one shot index per camera) by position in each folder.
pub(super) fn pair_by_order(
    names: &[String],
    shots: &[Shot],
) -> Result<Vec<Vec<Option<usize>>>, JobError> {
    let per: Vec<Vec<usize>> = (0..names.len())
        .map(|c| (0..shots.len()).filter(|&k| shots[k].camera == c).collect())
        .collect();
    let n = per[0].len();
    if let Some(c) = (1..names.len()).find(|&c| per[c].len() != n) {
        return Err(permanent(
            "invalid_input",
            format!(
                "cameras have different frame counts: {:?} has {n} images, {:?} has {}; pair by timestamp (`pairing: timestamp`) or remove the unpaired images",
                names[0],
                names[c],
                per[c].len()
            ),
        ));
    }
    Ok((0..n)
        .map(|f| per.iter().map(|v| Some(v[f])).collect())
        .collect())
}

/// The longest run of digits in a file name's stem, as a number.
fn timestamp(name: &str) -> Option<u64> {
    let file = name.rsplit('/').next().unwrap_or(name);
    let stem = file.rsplit_once('.').map_or(file, |(s, _)| s);
    stem.split(|c: char| !c.is_ascii_digit())
        .filter(|s| !s.is_empty())
        .max_by_key(|s| s.len())
        .and_then(|s| s.parse().ok())
}

/// Frame rows by timestamp: one per image of camera 0, each other camera's nearest image within
/// the tolerance (each image used at most once).
pub(super) fn pair_by_timestamp(
    names: &[String],
    shots: &[Shot],
    tolerance: u64,
) -> Result<Vec<Vec<Option<usize>>>, JobError> {
    let mut stamped: Vec<Vec<(u64, usize)>> = vec![Vec::new(); names.len()];
    for (k, s) in shots.iter().enumerate() {
        let t = timestamp(&s.name).ok_or_else(|| {
            permanent(
                "invalid_input",
                format!("{:?} has no timestamp (a run of digits) in its name, needed by `pairing: timestamp`", s.name),
            )
        })?;
        stamped[s.camera].push((t, k));
    }
    for v in &mut stamped {
        v.sort_unstable();
        if let Some(w) = v.windows(2).find(|w| w[0].0 == w[1].0) {
            return Err(permanent(
                "invalid_input",
                format!("two images of one camera have the timestamp {}", w[0].0),
            ));
        }
    }
    let mut used = vec![false; shots.len()];
    let mut rows = Vec::new();
    for &(t, k0) in &stamped[0] {
        let mut row = vec![Some(k0)];
        for cam in stamped.iter().skip(1) {
            let best = cam
                .iter()
                .filter(|(tc, k)| !used[*k] && tc.abs_diff(t) <= tolerance)
                .min_by_key(|(tc, _)| tc.abs_diff(t))
                .map(|(_, k)| *k);
            if let Some(k) = best {
                used[k] = true;
            }
            row.push(best);
        }
        rows.push(row);
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::timestamp;

    #[test]
    fn timestamps_are_the_longest_digit_run_of_the_stem() {
        assert_eq!(
            timestamp("cam0/1403636579763555584.png"),
            Some(1403636579763555584)
        );
        assert_eq!(
            timestamp("left/frame_0012_t1700000123.jpg"),
            Some(1700000123)
        );
        assert_eq!(timestamp("cam1/left.png"), None);
    }
}
