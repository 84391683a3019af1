//! Variance of the 3×3 Laplacian response, bit-compatible with
//! `cv2.Laplacian(gray, cv2.CV_64F, ksize=1).var()`.
//!
//! The response of an 8-bit image to the kernel [0 1 0; 1 −4 1; 0 1 0] is an integer in
//! [−1020, 1020], so Σr and Σr² can be accumulated *exactly* in integers: the only rounding is
//! the final division, which makes the result agree with OpenCV/numpy to ~1e-15 relative and
//! independent of summation order. Interior pixels run through a branch-free loop over five
//! equally long slices (bounds checks hoisted, so the compiler vectorises it); the two border
//! columns use explicit reflect-101 indexing.

use crate::io::Gray;

/// Pixels per inner chunk: 1020² · 4096 < 2³², so the chunk's Σr² fits a `u32` lane and Σr
/// (|Σr| ≤ 1020 · 4096) an `i32` lane, which keeps the loop in 32-bit SIMD.
const CHUNK: usize = 4096;

/// OpenCV's BORDER_REFLECT_101 (`gfedcb|abcdefgh|gfedcba`) for one step outside `0..n`.
/// For n = 1 there is nothing to reflect onto and OpenCV uses the pixel itself (checked with
/// cv2 on 1×N and N×1 images), which is what this returns.
#[inline]
fn reflect101(i: isize, n: usize) -> usize {
    if n == 1 {
        0
    } else if i < 0 {
        (-i) as usize
    } else if i as usize >= n {
        2 * (n - 1) - i as usize
    } else {
        i as usize
    }
}

/// Laplacian response at (x, y) with reflect-101 borders; used for borders and tiny images.
#[inline]
fn response_at(img: &Gray, x: usize, y: usize) -> i32 {
    let (w, h) = (img.width as usize, img.height as usize);
    let p = |xx: usize, yy: usize| i32::from(img.data[yy * w + xx]);
    let (xi, yi) = (x as isize, y as isize);
    let l = p(reflect101(xi - 1, w), y);
    let r = p(reflect101(xi + 1, w), y);
    let u = p(x, reflect101(yi - 1, h));
    let d = p(x, reflect101(yi + 1, h));
    l + r + u + d - 4 * p(x, y)
}

/// Σr and Σr² over x in 1..w−1 of one row, given the rows above and below (already
/// reflected for the first and last row). All three slices have the same length w ≥ 3.
#[inline]
fn row_interior(up: &[u8], cur: &[u8], down: &[u8]) -> (i64, u64) {
    let n = cur.len();
    let (mut s, mut q) = (0i64, 0u64);
    let mut start = 1;
    while start < n - 1 {
        let end = (start + CHUNK).min(n - 1);
        let len = end - start;
        let c = &cur[start..start + len];
        let l = &cur[start - 1..start - 1 + len];
        let r = &cur[start + 1..start + 1 + len];
        let u = &up[start..start + len];
        let d = &down[start..start + len];
        let (mut cs, mut cq) = (0i32, 0u32);
        for i in 0..len {
            let v = i32::from(u[i]) + i32::from(d[i]) + i32::from(l[i]) + i32::from(r[i])
                - 4 * i32::from(c[i]);
            cs += v;
            cq += (v * v) as u32;
        }
        s += i64::from(cs);
        q += u64::from(cq);
        start = end;
    }
    (s, q)
}

/// Exact Σr and Σr² over all pixels.
pub(crate) fn laplacian_sums(img: &Gray) -> (i64, u64) {
    let (w, h) = (img.width as usize, img.height as usize);
    let (mut s, mut q) = (0i64, 0u64);
    let mut add = |v: i32| {
        s += i64::from(v);
        q += (i64::from(v) * i64::from(v)) as u64;
    };
    if w < 3 {
        // Tiny images: everything is border.
        for y in 0..h {
            for x in 0..w {
                add(response_at(img, x, y));
            }
        }
        return (s, q);
    }
    for y in 0..h {
        add(response_at(img, 0, y));
        add(response_at(img, w - 1, y));
    }
    let (mut s2, mut q2) = (s, q);
    for y in 0..h {
        let up = img.row(reflect101(y as isize - 1, h));
        let down = img.row(reflect101(y as isize + 1, h));
        let (rs, rq) = row_interior(up, img.row(y), down);
        s2 += rs;
        q2 += rq;
    }
    (s2, q2)
}

/// Population variance of the Laplacian response (3×3 kernel [0 1 0; 1 −4 1; 0 1 0],
/// OpenCV's default border BORDER_REFLECT_101, every pixel counted), the classic
/// focus/blur measure: sharp edges give large responses, blur flattens them.
///
/// Equals `cv2.Laplacian(gray, cv2.CV_64F, ksize=1).var()` to ~1e-15 relative. Returns 0 for an
/// empty image. The value is not normalised: it grows with contrast and noise and depends on
/// resolution, so compare it only across images taken at the same scale (see
/// [`super::BlurParams`]).
pub fn laplacian_variance(img: &Gray) -> f64 {
    let n = u64::from(img.width) * u64::from(img.height);
    if n == 0 {
        return 0.0;
    }
    let (s, q) = laplacian_sums(img);
    // var = (n Σr² − (Σr)²) / n², numerator exact in i128.
    let num = i128::from(n) * i128::from(q) - i128::from(s) * i128::from(s);
    let nf = n as f64;
    num as f64 / (nf * nf)
}
