//! What a file is, decided from its first bytes (never from its name or the client's
//! Content-Type, which are often wrong).

/// Content classes the service accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sniffed {
    Png,
    Jpeg,
    Tiff,
    Zip,
    Gzip,
    /// Text that may be an IMU CSV log (validated separately).
    Text,
    Mp4,
    Matroska,
    Avi,
    Unknown,
}

impl Sniffed {
    /// Media type recorded for the stored file.
    pub fn media_type(self) -> &'static str {
        match self {
            Self::Png => "image/png",
            Self::Jpeg => "image/jpeg",
            Self::Tiff => "image/tiff",
            Self::Zip => "application/zip",
            Self::Gzip => "application/gzip",
            Self::Text => "text/csv",
            Self::Mp4 => "video/mp4",
            Self::Matroska => "video/x-matroska",
            Self::Avi => "video/x-msvideo",
            Self::Unknown => "application/octet-stream",
        }
    }

    pub fn is_image(self) -> bool {
        matches!(self, Self::Png | Self::Jpeg | Self::Tiff)
    }

    pub fn is_video(self) -> bool {
        matches!(self, Self::Mp4 | Self::Matroska | Self::Avi)
    }
}

/// Classify by magic numbers; `head` is the first bytes of the file (≥ 16 if available).
pub fn sniff(head: &[u8]) -> Sniffed {
    let starts = |m: &[u8]| head.starts_with(m);
    if starts(b"\x89PNG\r\n\x1a\n") {
        Sniffed::Png
    } else if starts(&[0xFF, 0xD8, 0xFF]) {
        Sniffed::Jpeg
    } else if starts(b"II*\0") || starts(b"MM\0*") {
        Sniffed::Tiff
    } else if starts(b"PK\x03\x04") || starts(b"PK\x05\x06") {
        Sniffed::Zip
    } else if starts(&[0x1F, 0x8B]) {
        Sniffed::Gzip
    } else if head.len() >= 8 && matches!(&head[4..8], b"ftyp" | b"moov" | b"mdat") {
        // ISO BMFF (MP4/MOV): a box size, then the first box type.
        Sniffed::Mp4
    } else if starts(&[0x1A, 0x45, 0xDF, 0xA3]) {
        Sniffed::Matroska
    } else if head.len() >= 12 && starts(b"RIFF") && &head[8..12] == b"AVI " {
        Sniffed::Avi
    } else if !head.is_empty() && looks_like_text(head) {
        Sniffed::Text
    } else {
        Sniffed::Unknown
    }
}

fn looks_like_text(head: &[u8]) -> bool {
    // UTF-8 BOM allowed; otherwise printable ASCII and common whitespace only.
    let body = head.strip_prefix(&[0xEF, 0xBB, 0xBF]).unwrap_or(head);
    body.iter()
        .all(|&b| b == b'\n' || b == b'\r' || b == b'\t' || (0x20..0x7F).contains(&b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn magic_numbers() {
        assert_eq!(sniff(b"\x89PNG\r\n\x1a\n0000"), Sniffed::Png);
        assert_eq!(sniff(&[0xFF, 0xD8, 0xFF, 0xE0]), Sniffed::Jpeg);
        assert_eq!(sniff(b"II*\0abcd"), Sniffed::Tiff);
        assert_eq!(sniff(b"PK\x03\x04rest"), Sniffed::Zip);
        assert_eq!(sniff(&[0x1F, 0x8B, 8, 0]), Sniffed::Gzip);
        assert_eq!(sniff(b"\0\0\0\x18ftypmp42"), Sniffed::Mp4);
        assert_eq!(sniff(b"#timestamp,w_x\n1,2"), Sniffed::Text);
        assert_eq!(sniff(b"\0\x01\x02garbage"), Sniffed::Unknown);
        assert_eq!(sniff(b""), Sniffed::Unknown);
    }
}
