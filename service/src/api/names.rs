//! The alphabet of device and sensor names, shared by job requests, token scopes and the
//! device list's cursor, so that the three cannot drift apart.

/// Whether `s` is a device or sensor name: [`name_pattern`], but never `.` or `..` (names
/// become path segments).
pub(crate) fn valid_name(s: &str) -> bool {
    name_pattern(s) && s != "." && s != ".."
}

/// Whether `s` matches `^[A-Za-z0-9._-]{1,128}$`, the alphabet of names and of the device
/// list's cursor.
pub(crate) fn name_pattern(s: &str) -> bool {
    (1..=128).contains(&s.len())
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'))
}

#[cfg(test)]
mod tests {
    use super::{name_pattern, valid_name};

    /// The cursor admits `.` and `..`; a name never does. Both refuse the empty string, 129
    /// characters and anything outside the alphabet.
    #[test]
    fn names_and_cursors_share_one_alphabet() {
        for ok in ["cam-0", "a.b_c", "X", &"a".repeat(128)] {
            assert!(valid_name(ok) && name_pattern(ok), "{ok}");
        }
        for dots in [".", ".."] {
            assert!(name_pattern(dots) && !valid_name(dots), "{dots}");
        }
        for bad in ["", "a/b", "a b", "é", &"a".repeat(129)] {
            assert!(!name_pattern(bad) && !valid_name(bad), "{bad}");
        }
    }
}
