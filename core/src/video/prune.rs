//! Cuts the index (`moov`) of an untrusted clip down to the boxes the demuxer reads, before
//! mp4-atom decodes it.
//!
//! Why: mp4-atom decodes every box it knows, wherever it appears, and some of its decoders loop
//! over a count taken from the file without consuming bytes per iteration (a version-0 `sgpd`
//! with four billion empty entries asked for 5 GiB; found by the `video` fuzz target). Auditing
//! every decoder of a library that knows over a hundred boxes is not a defence that lasts, so
//! instead every box the demuxer does not use is renamed `free` in place (mp4-atom skips those
//! without looking inside), and every sample entry other than H.264's is renamed to an opaque
//! code (mp4-atom keeps those as raw bytes) after its real code has been noted. What is left is
//! the short list of boxes below, whose decoders each consume bytes for every entry they count.

use super::demux::parse_header;
use super::error::VideoError;

/// Children kept under each container the demuxer walks into; everything else becomes `free`.
const KEEP: [(&[u8; 4], &[&[u8; 4]]); 8] = [
    (b"moov", &[b"mvhd", b"trak", b"mvex"]),
    (b"trak", &[b"tkhd", b"edts", b"mdia"]),
    (b"edts", &[b"elst"]),
    (b"mdia", &[b"mdhd", b"hdlr", b"minf"]),
    (b"minf", &[b"vmhd", b"dinf", b"stbl"]),
    (b"dinf", &[b"dref"]),
    (b"mvex", &[b"mehd", b"trex"]),
    (
        b"stbl",
        &[
            b"stsd", b"stts", b"ctts", b"stss", b"stsz", b"stsc", b"stco", b"co64",
        ],
    ),
];

/// Sample entries mp4-atom decodes for us; their children are cut to the decoder record.
const H264_ENTRIES: [&[u8; 4]; 2] = [b"avc1", b"avc3"];

/// The code other sample entries get: unknown to mp4-atom, so kept as raw bytes.
pub(crate) const OPAQUE_ENTRY: [u8; 4] = *b"cal0";

/// Bytes of a visual sample entry's fixed fields before its child boxes (ISO/IEC 14496-12
/// §12.1.3: 6 reserved, data reference index, then 70 bytes of visual fields).
const VISUAL_ENTRY_FIELDS: usize = 78;

/// What the walk saw that the renaming hides.
#[derive(Debug, Default)]
pub(crate) struct Pruned {
    /// Per `trak`, in file order: the original code of its first sample entry.
    pub first_entry: Vec<Option<[u8; 4]>>,
}

fn bad(msg: String) -> VideoError {
    VideoError::Malformed(msg)
}

/// One box inside a byte range: its code, where its body starts and where it ends.
struct Child {
    kind: [u8; 4],
    start: usize,
    body: usize,
    end: usize,
}

/// The boxes packed in `buf[from..to]`, in order. A remainder too short for a box header is
/// padding (QuickTime writes a 4-byte terminator) and is ignored, as mp4-atom does.
fn children(buf: &[u8], from: usize, to: usize) -> Result<Vec<Child>, VideoError> {
    let mut out = Vec::new();
    let mut pos = from;
    while let Some((kind, size, header)) = parse_header(&buf[pos..to], (to - pos) as u64)? {
        let left = to - pos;
        let size = usize::try_from(size).unwrap_or(usize::MAX);
        if size > left {
            return Err(bad(format!(
                "box '{}' inside the index declares {size} bytes where {left} are left",
                String::from_utf8_lossy(&kind)
            )));
        }
        out.push(Child {
            kind,
            start: pos,
            body: pos + header as usize,
            end: pos + size,
        });
        pos += size;
    }
    Ok(out)
}

fn rename(buf: &mut [u8], child: &Child, kind: &[u8; 4]) {
    buf[child.start + 4..child.start + 8].copy_from_slice(kind);
}

/// Prunes a whole `moov` box held in `buf` (header included). See the module doc.
pub(crate) fn prune(buf: &mut [u8]) -> Result<Pruned, VideoError> {
    let top = children(buf, 0, buf.len())?;
    let moov = match top.as_slice() {
        [only] if &only.kind == b"moov" => only,
        _ => return Err(bad("the index is not one moov box".into())),
    };
    let mut pruned = Pruned::default();
    let (kind, body, end) = (moov.kind, moov.body, moov.end);
    walk(buf, &kind, body, end, &mut pruned)?;
    Ok(pruned)
}

/// Renames the children of the container `kind` (body `buf[from..to]`) that the demuxer does
/// not read, and descends into the ones it keeps. The depth is bounded by [`KEEP`]'s nesting.
fn walk(
    buf: &mut [u8],
    kind: &[u8; 4],
    from: usize,
    to: usize,
    pruned: &mut Pruned,
) -> Result<(), VideoError> {
    let keep = KEEP
        .iter()
        .find(|(k, _)| *k == kind)
        .map(|(_, keep)| *keep)
        .unwrap_or(&[]);
    if kind == b"trak" {
        pruned.first_entry.push(None);
    }
    for child in children(buf, from, to)? {
        if !keep.contains(&&child.kind) {
            rename(buf, &child, b"free");
            continue;
        }
        if KEEP.iter().any(|(k, _)| *k == &child.kind) {
            walk(buf, &child.kind, child.body, child.end, pruned)?;
        } else if &child.kind == b"stsd" {
            let first = sample_entries(buf, &child)?;
            if let Some(slot) = pruned.first_entry.last_mut() {
                *slot = slot.or(first);
            }
        }
    }
    Ok(())
}

/// Prunes the entries of an `stsd` box and returns the original code of its first entry.
fn sample_entries(buf: &mut [u8], stsd: &Child) -> Result<Option<[u8; 4]>, VideoError> {
    // A full box: version and flags, then the entry count; the entries follow as boxes.
    let from = stsd.body + 8;
    if from > stsd.end {
        return Ok(None);
    }
    let mut first = None;
    for entry in children(buf, from, stsd.end)? {
        first = first.or(Some(entry.kind));
        if !H264_ENTRIES.contains(&&entry.kind) {
            rename(buf, &entry, &OPAQUE_ENTRY);
            continue;
        }
        let fields_end = entry.body + VISUAL_ENTRY_FIELDS;
        if fields_end > entry.end {
            continue; // too short for its fields: mp4-atom refuses it without reading on
        }
        for child in children(buf, fields_end, entry.end)? {
            if &child.kind != b"avcC" {
                rename(buf, &child, b"free");
            }
        }
    }
    Ok(first)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn boxed(kind: &[u8; 4], body: &[u8]) -> Vec<u8> {
        let mut out = ((body.len() + 8) as u32).to_be_bytes().to_vec();
        out.extend_from_slice(kind);
        out.extend_from_slice(body);
        out
    }

    fn kinds(buf: &[u8]) -> Vec<String> {
        (0..buf.len().saturating_sub(3))
            .filter_map(|i| std::str::from_utf8(&buf[i..i + 4]).ok())
            .filter(|s| ["free", "stsz", "sgpd", "avcC", "cal0", "hvc1", "udta"].contains(s))
            .map(String::from)
            .collect()
    }

    #[test]
    fn unread_boxes_become_free_and_other_codecs_opaque() {
        let sgpd = boxed(b"sgpd", &[0; 12]);
        let stsz = boxed(b"stsz", &[0; 12]);
        let mut avc_body = vec![0u8; VISUAL_ENTRY_FIELDS];
        avc_body.extend(boxed(b"avcC", &[1, 2, 3]));
        avc_body.extend(boxed(b"pasp", &[0; 8]));
        let mut hvc_body = vec![0u8; VISUAL_ENTRY_FIELDS];
        hvc_body.extend(boxed(b"hvcC", &[0; 4]));
        let stsd_of = |entry: Vec<u8>| {
            let mut b = vec![0, 0, 0, 0, 0, 0, 0, 1];
            b.extend(entry);
            boxed(b"stsd", &b)
        };
        let trak = |entry: Vec<u8>| {
            let stbl = boxed(
                b"stbl",
                &[stsd_of(entry), stsz.clone(), sgpd.clone()].concat(),
            );
            let minf = boxed(b"minf", &stbl);
            boxed(b"trak", &boxed(b"mdia", &minf))
        };
        let moov_body = [
            trak(boxed(b"avc1", &avc_body)),
            trak(boxed(b"hvc1", &hvc_body)),
            boxed(b"udta", &[0; 4]),
        ]
        .concat();
        let mut moov = boxed(b"moov", &moov_body);
        let pruned = prune(&mut moov).expect("well-formed");
        assert_eq!(pruned.first_entry, vec![Some(*b"avc1"), Some(*b"hvc1")]);
        let seen = kinds(&moov);
        assert!(
            !seen
                .iter()
                .any(|k| k == "sgpd" || k == "udta" || k == "hvc1")
        );
        assert_eq!(seen.iter().filter(|k| *k == "stsz").count(), 2);
        assert_eq!(seen.iter().filter(|k| *k == "avcC").count(), 1);
        assert_eq!(seen.iter().filter(|k| *k == "cal0").count(), 1);
        // pasp, the sgpd of each stbl and the udta.
        assert_eq!(seen.iter().filter(|k| *k == "free").count(), 4);
    }

    #[test]
    fn a_child_larger_than_its_parent_is_refused() {
        let mut stbl = boxed(b"stbl", &boxed(b"stsz", &[0; 12]));
        stbl[11] = 200; // stsz now claims 200 bytes
        let mut moov = boxed(
            b"moov",
            &boxed(b"trak", &boxed(b"mdia", &boxed(b"minf", &stbl))),
        );
        assert!(matches!(prune(&mut moov), Err(VideoError::Malformed(_))));
    }
}
