//! The singular-value blur feature β of Su, Lu & Tan, "Blurred image region detection and
//! classification", ACM Multimedia 2011: β = Σ_{i≤k} σ_i / Σ_i σ_i over the singular values of
//! the grey image. Blur removes fine detail, which lives in the small singular values, so the
//! top k carry a larger share of the total and β rises.
//!
//! A full SVD is slow and we need no singular vectors, so we use σ_i = √λ_i(G) with G the Gram
//! matrix of the smaller side (G = A·Aᵀ for a wide image). Two observations make this both fast
//! and accurate:
//! - the pixels are integers 0..=255 and β is scale-invariant, so we work on the raw integers:
//!   every product and partial sum in G is an integer below 2⁵³, hence G is computed *exactly*
//!   by an ordinary f64 matmul, whatever its summation order;
//! - the remaining error is the eigensolver's, |δλ| ≲ ε·λ_max, which squares the condition
//!   number: a singular value σ gets an error of about ε·λ_max / (2σ), large for images with
//!   (nearly) zero singular values (e.g. blank rows or columns). We bound that error on β from
//!   the eigenvalues themselves and fall back to a direct SVD when the bound exceeds
//!   [`FALLBACK_BOUND`].

use faer::diag::Diag;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::matmul::triangular::{self as tri, BlockStructure};
use faer::linalg::{evd, svd};
use faer::{Accum, Mat, MatRef, Par};

use crate::error::{CoreError, CoreResult};
use crate::io::Gray;

/// Largest estimated β error accepted from the eigenvalue route. The estimate
/// Σ_i min(ε λ_max / 2σ_i, √(ε λ_max)) / Σσ was between 30× and 10⁵× larger than the true error
/// on the 22 shared test images (vs numpy's SVD), so 5e-9 keeps the result within 1e-9.
pub(crate) const FALLBACK_BOUND: f64 = 5e-9;

/// Which computation produced the singular values (exposed for tests and benchmarks).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Route {
    Gram,
    Svd,
}

/// Largest short side on which β is computed at full resolution. The cost grows with the cube
/// of the short side (a 5000×5000 frame took 73 s and 657 MB, issue D7); above this the image
/// is first reduced by [`reduction_factor`]. 2304 keeps 4K UHD (3840×2160) and every smaller
/// frame exact and bounds the worst case to a few seconds.
pub const MAX_BETA_SIDE: usize = 2304;

/// The integer factor f by which an image is box-reduced before β: the smallest with
/// short side / f ≤ [`MAX_BETA_SIDE`] (1 for every image up to that size).
pub fn reduction_factor(width: u32, height: u32) -> usize {
    (width.min(height) as usize).div_ceil(MAX_BETA_SIDE).max(1)
}

/// The image as an n×m column-major f64 matrix B whose m columns are the m "short-side" vectors
/// (rows of a wide image, columns of a tall one), so that G = Bᵀ·B is m×m with m = min(w, h).
///
/// With a reduction factor f > 1, each entry is the *sum* of an f×f block (trailing partial
/// blocks dropped): still integers, so G stays exact (f ≤ 8 keeps every product and partial
/// sum below 2⁵³ up to the 16384-px limit), and β, being scale-invariant, is that of the box-
/// downscaled image.
fn short_side_matrix(img: &Gray, f: usize) -> Mat<f64> {
    let (w, h) = (img.width as usize, img.height as usize);
    let d = &img.data;
    if f > 1 {
        let (rw, rh) = (w / f, h / f);
        let block = |x: usize, y: usize| -> f64 {
            let mut acc = 0u32;
            for yy in y * f..(y + 1) * f {
                for &p in &d[yy * w + x * f..yy * w + (x + 1) * f] {
                    acc += u32::from(p);
                }
            }
            f64::from(acc)
        };
        return if rh <= rw {
            Mat::from_fn(rw, rh, &block)
        } else {
            Mat::from_fn(rh, rw, |i, j| block(j, i))
        };
    }
    if h <= w {
        // Column j of B = row j of the image (contiguous).
        Mat::from_fn(w, h, |i, j| f64::from(d[j * w + i]))
    } else {
        // Column j of B = column j of the image.
        Mat::from_fn(h, w, |i, j| f64::from(d[i * w + j]))
    }
}

/// Eigenvalues (ascending) of the exact Gram matrix Bᵀ·B.
fn gram_eigenvalues(b: MatRef<'_, f64>, par: Par) -> CoreResult<Vec<f64>> {
    let m = b.ncols();
    let mut g = Mat::<f64>::zeros(m, m);
    // Only the lower triangle is computed and read: half the flops of a full product.
    tri::matmul(
        g.as_mut(),
        BlockStructure::TriangularLower,
        Accum::Replace,
        b.transpose(),
        BlockStructure::Rectangular,
        b,
        BlockStructure::Rectangular,
        1.0,
        par,
    );
    let mut s = Diag::<f64>::zeros(m);
    let req = evd::self_adjoint_evd_scratch::<f64>(
        m,
        evd::ComputeEigenvectors::No,
        par,
        Default::default(),
    );
    let mut buf = MemBuffer::new(req);
    evd::self_adjoint_evd(
        g.as_ref(),
        s.as_mut(),
        None,
        par,
        MemStack::new(&mut buf),
        Default::default(),
    )
    .map_err(|e| CoreError::NoSolution(format!("eigenvalue solver failed: {e:?}")))?;
    Ok(s.column_vector().iter().copied().collect())
}

/// Singular values of B by a direct SVD (no vectors), descending.
fn direct_singular_values(b: MatRef<'_, f64>, par: Par) -> CoreResult<Vec<f64>> {
    let m = b.ncols().min(b.nrows());
    let mut s = Diag::<f64>::zeros(m);
    let req = svd::svd_scratch::<f64>(
        b.nrows(),
        b.ncols(),
        svd::ComputeSvdVectors::No,
        svd::ComputeSvdVectors::No,
        par,
        Default::default(),
    );
    let mut buf = MemBuffer::new(req);
    svd::svd(
        b,
        s.as_mut(),
        None,
        None,
        par,
        MemStack::new(&mut buf),
        Default::default(),
    )
    .map_err(|e| CoreError::NoSolution(format!("SVD failed: {e:?}")))?;
    let mut v: Vec<f64> = s.column_vector().iter().map(|x| x.abs()).collect();
    v.sort_by(|a, b| b.total_cmp(a));
    Ok(v)
}

/// Upper estimate of the error on β caused by eigenvalue errors of size ε·λ_max.
fn gram_error_bound(eig_desc: &[f64], sigma_sum: f64) -> f64 {
    let lmax = eig_desc.first().copied().unwrap_or(0.0).max(0.0);
    let tau = f64::EPSILON * lmax;
    if tau == 0.0 || sigma_sum == 0.0 {
        return 0.0;
    }
    let e: f64 = eig_desc
        .iter()
        .map(|&l| {
            if l > tau {
                tau / (2.0 * l.sqrt())
            } else {
                tau.sqrt()
            }
        })
        .sum();
    e / sigma_sum
}

/// Singular values of the image (in pixel units 0..=255), descending, and the route used.
pub(crate) fn singular_values(img: &Gray, par: Par) -> CoreResult<(Vec<f64>, Route)> {
    singular_values_reduced(img, par, reduction_factor(img.width, img.height))
}

/// [`singular_values`] of the image box-reduced by `f` (≥ 1).
fn singular_values_reduced(img: &Gray, par: Par, f: usize) -> CoreResult<(Vec<f64>, Route)> {
    let b = short_side_matrix(img, f.max(1));
    let mut eig = gram_eigenvalues(b.as_ref(), par)?;
    eig.reverse();
    // Tiny negative eigenvalues are rounding noise on a zero singular value.
    let sigma: Vec<f64> = eig.iter().map(|&l| l.max(0.0).sqrt()).collect();
    let total: f64 = sigma.iter().sum();
    if gram_error_bound(&eig, total) <= FALLBACK_BOUND {
        Ok((sigma, Route::Gram))
    } else {
        Ok((direct_singular_values(b.as_ref(), par)?, Route::Svd))
    }
}

/// β from singular values sorted in descending order.
pub(crate) fn beta_from_sorted(sigma: &[f64], k: usize) -> f64 {
    let total: f64 = sigma.iter().sum();
    if total <= 0.0 {
        // An all-black image: no detail at all, the limit of a rank-one (constant) image.
        return 1.0;
    }
    let top: f64 = sigma.iter().take(k).sum();
    (top / total).clamp(0.0, 1.0)
}

/// The singular-value blur feature β (Su, Lu & Tan, ACM MM 2011): the share of the k largest
/// singular values in the sum of all singular values of the whole grey image. Higher means
/// blurrier (fine detail, carried by the small singular values, is gone).
///
/// Equals `s = np.linalg.svd(gray / 255., compute_uv=False); s[:k].sum() / s.sum()` to better
/// than 1e-9 absolute (see the module docs for how this is ensured without a full SVD). An
/// all-black image gives 1.0 (numpy would give NaN); `k ≥ min(width, height)` gives 1.0.
/// Images whose short side exceeds [`MAX_BETA_SIDE`] are box-reduced first (see there).
/// Runs single-threaded: callers parallelise across images.
pub fn svd_beta(img: &Gray, k: usize) -> CoreResult<f64> {
    if k == 0 {
        return Err(CoreError::param("k", "must be at least 1"));
    }
    if img.width == 0 || img.height == 0 {
        return Err(CoreError::input("image has no pixels"));
    }
    let (sigma, _) = singular_values(img, Par::Seq)?;
    Ok(beta_from_sorted(&sigma, k))
}

/// Largest short side on which β of a *video frame* is computed at full resolution. β costs
/// the cube of the short side (about 60 ms for a 640×480 frame, 1.4 s for 1920×1080 on one
/// core), which would hold clip scoring far below real time; frames with a larger short side
/// are box-reduced first by [`clip_reduction_factor`] (1080p and 720p to 640×360), which keeps
/// 1080p scoring above 30 frames/s on two cores. A VGA frame keeps its exact β.
pub const MAX_CLIP_BETA_SIDE: usize = 480;

/// The integer factor by which a video frame is box-reduced before β: the smallest with
/// short side / f ≤ [`MAX_CLIP_BETA_SIDE`].
pub fn clip_reduction_factor(width: u32, height: u32) -> usize {
    (width.min(height) as usize)
        .div_ceil(MAX_CLIP_BETA_SIDE)
        .max(reduction_factor(width, height))
}

/// β of the image box-reduced by the integer factor `f` (≥ 1; see [`svd_beta`]), the
/// clip scorer's β with `f` = [`clip_reduction_factor`]. β being scale-invariant, this is
/// the β of the box-downscaled image.
pub fn svd_beta_reduced(img: &Gray, k: usize, f: usize) -> CoreResult<f64> {
    if k == 0 {
        return Err(CoreError::param("k", "must be at least 1"));
    }
    if img.width as usize / f.max(1) == 0 || img.height as usize / f.max(1) == 0 {
        return Err(CoreError::input("image has no pixels at that reduction"));
    }
    let (sigma, _) = singular_values_reduced(img, Par::Seq, f)?;
    Ok(beta_from_sorted(&sigma, k))
}
