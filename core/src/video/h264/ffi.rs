//! The one place that calls OpenH264 below the `openh264` crate's safe wrapper.
//!
//! Why: the wrapper's `decode()` stamps every picture with the timestamp of the call that
//! returned it, but with B-frames OpenH264 returns pictures later than, and in another order
//! than, the samples that made them. OpenH264 itself carries an input timestamp
//! (`uiInBsTimeStamp`) through its reorder buffer to the picture it belongs to
//! (`uiOutYuvTimeStamp`), so we pass each sample's decode-order index there and get back,
//! with every picture, exactly which sample it is. The wrapper does not expose those fields.

use std::os::raw::{c_int, c_void};
use std::ptr::null_mut;

use openh264::OpenH264API;
use openh264::decoder::{Decoder, DecoderConfig, Flush};
use openh264_sys2::{
    DECODER_OPTION, DECODER_OPTION_NUM_OF_FRAMES_REMAINING_IN_BUFFER, SBufferInfo, videoFormatI420,
};

/// A decoded 4:2:0 picture borrowed from the decoder until the next call.
pub(crate) struct Picture<'a> {
    /// The token passed with the sample that produced it.
    pub token: u64,
    pub width: usize,
    pub height: usize,
    pub y: &'a [u8],
    pub y_stride: usize,
    pub u: &'a [u8],
    pub v: &'a [u8],
    pub uv_stride: usize,
}

/// OpenH264 with pictures tagged by token and no implicit flushing (flushing after every
/// call would hand out buffered pictures before the B-frames that precede them).
pub(crate) struct RawDecoder {
    inner: Decoder,
}

impl RawDecoder {
    pub fn new() -> Result<Self, String> {
        let config = DecoderConfig::new().flush_after_decode(Flush::NoFlush);
        let inner = Decoder::with_api_config(OpenH264API::from_source(), config)
            .map_err(|e| e.to_string())?;
        Ok(Self { inner })
    }

    /// Decodes one access unit in Annex B form. Returns OpenH264's state flags (0 = no error)
    /// and the picture that came out, if any (possibly one of an earlier sample).
    pub fn decode(&mut self, au: &[u8], token: u64) -> (i64, Option<Picture<'_>>) {
        let Ok(len) = c_int::try_from(au.len()) else {
            return (i64::from(openh264_sys2::dsInvalidArgument), None);
        };
        let mut dst = [null_mut::<u8>(); 3];
        let mut info = SBufferInfo {
            uiInBsTimeStamp: token,
            ..SBufferInfo::default()
        };
        // SAFETY: `au` outlives the call and `len` is its length; `dst` and `info` are valid
        // out-parameters of the sizes OpenH264 expects (three plane pointers, one SBufferInfo).
        let state = unsafe {
            self.inner.raw_api().decode_frame_no_delay(
                au.as_ptr(),
                len,
                dst.as_mut_ptr(),
                &raw mut info,
            )
        };
        // SAFETY: the pointers in `dst` were just produced by the decoder for `info`, and the
        // returned picture borrows `self` mutably, so no further call can invalidate them.
        (i64::from(state), unsafe { picture(&dst, &info) })
    }

    /// Pictures still held in the decoder's reorder buffer.
    pub fn buffered(&mut self) -> usize {
        let mut n: DECODER_OPTION = 0;
        // SAFETY: the option is an `int` written by the decoder into `n`.
        let rc = unsafe {
            self.inner.raw_api().get_option(
                DECODER_OPTION_NUM_OF_FRAMES_REMAINING_IN_BUFFER,
                (&raw mut n).cast::<c_void>(),
            )
        };
        if rc == 0 {
            usize::try_from(n).unwrap_or(0)
        } else {
            0
        }
    }

    /// Takes one picture out of the reorder buffer at the end of the stream.
    pub fn flush_one(&mut self) -> Option<Picture<'_>> {
        let mut dst = [null_mut::<u8>(); 3];
        let mut info = SBufferInfo::default();
        // SAFETY: as in `decode`, valid out-parameters.
        unsafe {
            self.inner
                .raw_api()
                .flush_frame(dst.as_mut_ptr(), &raw mut info);
        }
        // SAFETY: as in `decode`.
        unsafe { picture(&dst, &info) }
    }
}

/// Wraps the decoder's output pointers after checking the sizes it reported.
///
/// # Safety
/// `dst` and `info` must come from the decoder call just made, and the result must not
/// outlive the next call into the decoder.
unsafe fn picture<'a>(dst: &[*mut u8; 3], info: &SBufferInfo) -> Option<Picture<'a>> {
    if info.iBufferStatus != 1 || dst.iter().any(|p| p.is_null()) {
        return None;
    }
    // SAFETY: with iBufferStatus == 1 the decoder fills the system-buffer variant.
    let sb = unsafe { info.UsrData.sSystemBuffer };
    if sb.iFormat != videoFormatI420 as c_int {
        return None;
    }
    let width = usize::try_from(sb.iWidth).ok().filter(|&w| w > 0)?;
    let height = usize::try_from(sb.iHeight).ok().filter(|&h| h > 0)?;
    let y_stride = usize::try_from(sb.iStride[0])
        .ok()
        .filter(|&s| s >= width)?;
    let uv_stride = usize::try_from(sb.iStride[1])
        .ok()
        .filter(|&s| s >= width.div_ceil(2))?;
    let y_len = y_stride.checked_mul(height)?;
    let uv_len = uv_stride.checked_mul(height / 2)?;
    // SAFETY: OpenH264 allocates every plane with at least `height` (resp. `height / 2`)
    // rows of its stride; the pointers are non-null and valid until the next decoder call.
    unsafe {
        Some(Picture {
            token: info.uiOutYuvTimeStamp,
            width,
            height,
            y: std::slice::from_raw_parts(dst[0], y_len),
            y_stride,
            u: std::slice::from_raw_parts(dst[1], uv_len),
            v: std::slice::from_raw_parts(dst[2], uv_len),
            uv_stride,
        })
    }
}
