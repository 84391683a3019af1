//! The YAML Caliper writes and reads, by hand.
//!
//! Why not a YAML library: OpenCV's FileStorage starts its files with `%YAML:1.0`, which is not a
//! valid YAML 1.x directive (the spec wants `%YAML 1.1`), and tags matrices `!!opencv-matrix`, a
//! secondary-handle tag no generic parser resolves; both make conforming parsers refuse the file
//! (see `/work/shared/docs/formats.md`). The three formats Caliper exchanges only use a small,
//! regular subset, so a strict reader for exactly that subset is both smaller and safer than
//! pre-processing files for a general parser:
//!
//! * an optional `%YAML…` first line and an optional `---` document start;
//! * block mappings (`key: value`, nested by indentation, spaces only);
//! * block sequences (`- item`, items being scalars or flow sequences; Kalibr's `T_cn_cnm1`);
//! * flow sequences `[a, b, [c, d]]`, possibly spread over several lines (OpenCV wraps `data`);
//! * the tag `!!opencv-matrix` on a block mapping;
//! * plain, `'single'` and `"double"` quoted scalars, and `#` comments.
//!
//! Anything else (anchors, aliases, flow mappings, block scalars, other tags, several documents)
//! is refused with the line number, rather than guessed at.
//!
//! Numbers are written so that they read back bit-for-bit: the shortest decimal that round-trips
//! (Rust's `{:e}`), in C notation with a `.` in the mantissa and a signed exponent
//! (`5.3591573396163199e+02`), because YAML 1.1 resolvers (PyYAML, which Kalibr uses) only
//! recognise a float when it has a dot and a signed exponent: `1e-5` would be read as a string.
//!
//! Files: `write` (number, string and flow-sequence formatting, including the public
//! [`yaml_number`]), `parse` (the strict reader of
//! the subset above into [`Node`]s), `access` (typed access to parsed values with the key named
//! in every error) and `matrix` (OpenCV `!!opencv-matrix` and ROS `rows`/`cols`/`data`
//! matrices). The readers serve the public importers `read_opencv_yaml`, `read_ros_yaml` and
//! `read_kalibr_yaml`/`read_kalibr_camchain`.

mod access;
mod matrix;
mod parse;
mod write;

pub(crate) use access::{
    Fields, as_f64, as_int, as_map, as_seq, as_str, bad, f64_array, f64_seq, positive_u32,
};
#[cfg(test)]
pub(crate) use access::{parse_f32, parse_f64};
pub(crate) use matrix::{Matrix, opencv_matrix, ros_matrix};
pub(crate) use parse::{Node, OPENCV_MATRIX_TAG, parse};
pub use write::yaml_number;
pub(crate) use write::{NanStyle, flow, flow_wrapped, fmt_f32, fmt_f64, quote};
