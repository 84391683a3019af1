//! A quick check that a text upload is an IMU log (EuRoC-style CSV), done at upload so that
//! a wrong file is refused at once. Full parsing belongs to the IMU job kinds.

use std::io::{BufRead, BufReader, Read};
use std::path::Path;

/// Look at the first lines (decompressing gzip) and require numeric rows of at least 7
/// columns: timestamp, 3 gyro axes, 3 accelerometer axes.
pub fn validate(path: &Path, gzip: bool) -> Result<(), String> {
    let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let reader: Box<dyn Read> = if gzip {
        Box::new(flate2::read::MultiGzDecoder::new(file))
    } else {
        Box::new(file)
    };
    // Read at most 1 MiB of decompressed text: enough for the header and many rows.
    let reader = BufReader::new(reader.take(1 << 20));
    let mut good = 0;
    let mut seen = 0;
    for line in reader.lines() {
        let line = line.map_err(|e| format!("not a text/gzip CSV: {e}"))?;
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') || t.starts_with("timestamp") {
            continue;
        }
        seen += 1;
        let fields: Vec<&str> = t
            .split([',', ';', ' ', '\t'])
            .filter(|f| !f.is_empty())
            .collect();
        if fields.len() >= 7
            && fields
                .iter()
                .take(7)
                .all(|f| f.trim().parse::<f64>().is_ok())
        {
            good += 1;
        }
        if seen >= 200 {
            break;
        }
    }
    if good == 0 {
        return Err("no row of numbers `timestamp, gx, gy, gz, ax, ay, az` in the first lines (EuRoC CSV expected)".into());
    }
    Ok(())
}
