//! A peer kernel estimator for `blind_eval`: the IPOL implementation of Pan et al.'s L0
//! gradient prior (J. Anger, G. Facciolo, M. Delbracio, "Blind image deblurring using the l0
//! gradient prior", Image Processing On Line 9, 2019), run as an external program on the same
//! blurred 8-bit image with the same kernel window, its kernel then scored by the same TV
//! restoration and error ratio as ours.
//!
//! `BLIND_PEER` names a command called as `CMD KS BLURRED.png KERNEL.asc`; the IPOL program
//! `estimate-kernel` takes exactly that (its `iio` writes `.asc`: a `w h d n` header, then the
//! values). Nothing of it is in this repository: build it beside the project (see
//! `core/benches/deconv_set.md`).

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use caliper_core::deconv::{Plane, Psf};

/// Runs the peer on `blurred` with a `ks × ks` window in `dir`; its kernel and the wall time
/// of the call, or a message saying what went wrong.
pub fn estimate(
    cmd: &str,
    blurred: &Plane,
    ks: usize,
    dir: &Path,
    stem: &str,
) -> Result<(Psf, f64), String> {
    let input = dir.join(format!("{stem}_blurred.png"));
    let output = dir.join(format!("{stem}_peer.asc"));
    let g = blurred.to_gray();
    image::GrayImage::from_raw(g.width, g.height, g.data)
        .ok_or("image size")?
        .save(&input)
        .map_err(|e| e.to_string())?;
    let t = Instant::now();
    let status = Command::new(cmd)
        .arg(ks.to_string())
        .arg(&input)
        .arg(&output)
        .output()
        .map_err(|e| format!("{cmd}: {e}"))?;
    let secs = t.elapsed().as_secs_f64();
    if !status.status.success() {
        return Err(format!(
            "{cmd} failed: {}",
            String::from_utf8_lossy(&status.stderr)
        ));
    }
    let text = std::fs::read_to_string(&output).map_err(|e| e.to_string())?;
    let mut it = text.split_whitespace();
    let mut next = || -> Result<f64, String> {
        it.next()
            .ok_or("short file")?
            .parse::<f64>()
            .map_err(|e| e.to_string())
    };
    let (w, h) = (next()? as usize, next()? as usize);
    let (_d, _n) = (next()?, next()?);
    let mut data = Vec::with_capacity(w * h);
    for _ in 0..w * h {
        data.push(next()?.max(0.0));
    }
    let psf = if data.iter().sum::<f64>() > 0.0 {
        Psf::from_weights(w, h, data).map_err(|e| e.to_string())?
    } else {
        Psf::identity()
    };
    Ok((psf, secs))
}
