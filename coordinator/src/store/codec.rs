//! How an accepted output is stored: losslessly, in about a sixth of its
//! JSON text. A worker's upload is mostly trajectories (three arrays of
//! full-precision floats per kept episode), which JSON spells in ~20
//! bytes a value and general-purpose compressors shrink only ~3x (the
//! digits of a full-precision float are close to random). Here each array
//! is stored as the bit patterns of its values, each XORed with the one
//! before (neighbouring samples of a smooth trajectory share sign,
//! exponent and leading mantissa bits, so the XOR is mostly zero bytes),
//! the bytes regrouped by significance (all first bytes, then all second
//! bytes, ...), and the whole compressed with zstd. Everything else of the
//! output stays JSON, so a field added to `JobOutput` is stored without a
//! change here. Decoding gives back the identical `f64` bit patterns.
//!
//! Layout: [`MAGIC`], then zstd of: the JSON length (u32 LE), the JSON of
//! the output with its trajectory arrays emptied, per episode the lengths
//! of `com_t`, `com_x`, `com_z` (u32 LE each), then the shuffled XOR
//! stream of every array in that order.

use std::cell::RefCell;

use anyhow::{bail, ensure, Context};
use shared::api::JobOutput;

/// First bytes of a stored output in this encoding (older rows hold the
/// JSON text itself).
pub const MAGIC: &[u8; 4] = b"irz1";

/// zstd level: the ratio flattens above it while the time keeps growing.
const LEVEL: i32 = 3;

/// Encodes an output for storage. Takes the output, so that its
/// trajectories move into the byte planes instead of being copied.
pub fn encode(mut output: JobOutput) -> anyhow::Result<Vec<u8>> {
    let mut arrays: Vec<Vec<f64>> = Vec::with_capacity(output.episodes.len() * 3);
    for ep in &mut output.episodes {
        arrays.extend([
            std::mem::take(&mut ep.com_t),
            std::mem::take(&mut ep.com_x),
            std::mem::take(&mut ep.com_z),
        ]);
    }
    // The output with its trajectory arrays emptied.
    let json = serde_json::to_vec(&output).context("encoding the output's fields")?;
    let n: usize = arrays.iter().map(Vec::len).sum();
    let mut raw = Vec::with_capacity(4 + json.len() + 4 * arrays.len() + 8 * n);
    raw.extend_from_slice(&len32(json.len())?.to_le_bytes());
    raw.extend_from_slice(&json);
    for a in &arrays {
        raw.extend_from_slice(&len32(a.len())?.to_le_bytes());
    }
    let start = raw.len();
    raw.resize(start + 8 * n, 0);
    let planes = &mut raw[start..];
    let mut i = 0;
    for a in &arrays {
        let mut prev = 0u64;
        for v in a.iter() {
            let bits = v.to_bits();
            let x = (bits ^ prev).to_le_bytes();
            for (j, b) in x.iter().enumerate() {
                planes[j * n + i] = *b;
            }
            prev = bits;
            i += 1;
        }
    }
    drop(arrays);
    let z = compress(&raw).context("compressing")?;
    let mut out = Vec::with_capacity(MAGIC.len() + z.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&z);
    Ok(out)
}

thread_local! {
    /// One zstd context per thread, kept: making one allocates and clears
    /// its tables, which cost about as much as compressing an upload.
    static COMPRESSOR: RefCell<Option<zstd::bulk::Compressor<'static>>> =
        const { RefCell::new(None) };
}

/// zstd at [`LEVEL`] with this thread's kept context.
fn compress(raw: &[u8]) -> std::io::Result<Vec<u8>> {
    COMPRESSOR.with(|c| {
        let mut c = c.borrow_mut();
        let c = match &mut *c {
            Some(c) => c,
            empty => empty.insert(zstd::bulk::Compressor::new(LEVEL)?),
        };
        c.compress(raw)
    })
}

/// Decodes what [`encode`] stored; a row stored before this encoding (the
/// output's JSON text) is read as JSON.
pub fn decode(stored: &[u8]) -> anyhow::Result<JobOutput> {
    let Some(z) = stored.strip_prefix(MAGIC.as_slice()) else {
        return serde_json::from_slice(stored).context("stored output (json)");
    };
    let raw = zstd::stream::decode_all(z).context("decompressing a stored output")?;
    let mut r = Reader(&raw);
    let json_len = r.u32()? as usize;
    let mut out: JobOutput =
        serde_json::from_slice(r.take(json_len)?).context("stored output fields")?;
    let mut lens = Vec::with_capacity(out.episodes.len() * 3);
    for _ in 0..out.episodes.len() * 3 {
        lens.push(r.u32()? as usize);
    }
    let n: usize = lens.iter().sum();
    let planes = r.take(8 * n)?;
    ensure!(
        r.0.is_empty(),
        "stored output: {} trailing bytes",
        r.0.len()
    );
    let mut i = 0;
    let mut arrays = lens.iter().map(|&len| {
        let mut prev = 0u64;
        (0..len)
            .map(|_| {
                let mut x = [0u8; 8];
                for (j, b) in x.iter_mut().enumerate() {
                    *b = planes[j * n + i];
                }
                i += 1;
                prev ^= u64::from_le_bytes(x);
                f64::from_bits(prev)
            })
            .collect::<Vec<f64>>()
    });
    for ep in &mut out.episodes {
        match (arrays.next(), arrays.next(), arrays.next()) {
            (Some(t), Some(x), Some(z)) => {
                ep.com_t = t;
                ep.com_x = x;
                ep.com_z = z;
            }
            _ => bail!("stored output: fewer trajectory arrays than episodes"),
        }
    }
    Ok(out)
}

fn len32(n: usize) -> anyhow::Result<u32> {
    u32::try_from(n).context("an output part longer than 4 GiB")
}

struct Reader<'a>(&'a [u8]);

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> anyhow::Result<&'a [u8]> {
        ensure!(self.0.len() >= n, "stored output is truncated");
        let (head, tail) = self.0.split_at(n);
        self.0 = tail;
        Ok(head)
    }

    fn u32(&mut self) -> anyhow::Result<u32> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::analysis::EpisodeRecord;

    fn output() -> JobOutput {
        let ep = |k: usize| EpisodeRecord {
            com_t: (0..400)
                .map(|i| i as f64 * 0.005 + k as f64 * 1e-9)
                .collect(),
            com_x: (0..400)
                .map(|i| (0.05 + 0.01 * k as f64) * (i as f64 / 127.0).sin() + 1e-13 * i as f64)
                .collect(),
            com_z: (0..400).map(|i| 0.55 + 0.001 * i as f64 + 1e-17).collect(),
            ret: 900.5 + k as f64,
            torque_usage: 41.25,
            steps: 40,
        };
        JobOutput {
            final_success_rate: 0.9,
            env_steps: 123_456,
            successes_found: 10,
            successes_wanted: 10,
            sampling_attempts: 14,
            episodes: (0..10).map(ep).collect(),
            train_secs: 12.5,
            sample_secs: 1.25,
        }
    }

    #[test]
    fn outputs_come_back_bit_for_bit_and_much_smaller() {
        let mut o = output();
        // Values whose bits a decimal round trip would not keep apart.
        o.episodes[0].com_x[1] = -0.0;
        o.episodes[0].com_x[2] = f64::MIN_POSITIVE / 3.0;
        o.episodes[1].com_z[5] = f64::MAX;
        let stored = encode(o.clone()).unwrap();
        assert!(stored.starts_with(MAGIC));
        let back = decode(&stored).unwrap();
        let bits = |o: &JobOutput| -> Vec<u64> {
            o.episodes
                .iter()
                .flat_map(|e| e.com_t.iter().chain(&e.com_x).chain(&e.com_z))
                .map(|v| v.to_bits())
                .collect()
        };
        assert_eq!(bits(&back), bits(&o));
        assert_eq!(
            serde_json::to_string(&back).unwrap(),
            serde_json::to_string(&o).unwrap()
        );
        let json = serde_json::to_vec(&o).unwrap().len();
        assert!(stored.len() * 4 < json, "{} of {json} bytes", stored.len());
    }

    #[test]
    fn json_rows_of_older_databases_still_read() {
        let o = output();
        let text = serde_json::to_vec(&o).unwrap();
        assert_eq!(decode(&text).unwrap(), o);
        assert_eq!(
            decode(&encode(JobOutput::default()).unwrap()).unwrap(),
            JobOutput::default()
        );
    }

    #[test]
    fn damaged_rows_are_errors_not_panics() {
        let stored = encode(output()).unwrap();
        assert!(decode(&stored[..stored.len() / 2]).is_err());
        let mut raw = MAGIC.to_vec();
        zstd::stream::copy_encode(&[9u8, 0, 0, 0, b'{'][..], &mut raw, 1).unwrap();
        assert!(decode(&raw).is_err());
    }
}
