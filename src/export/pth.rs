//! `.pth` files as `torch.save(numpy_array, path)` writes them, so that `torch.load(path,
//! weights_only=False)` returns the numpy array (what GeoTransformer's 3DMatch loader calls on every
//! cloud, `_load_point_cloud`).
//!
//! PyTorch's serialization is a zip archive of stored (uncompressed) records under one folder named
//! after the file (`cloud_bin_0/` for `cloud_bin_0.pth`):
//!
//! ```text
//! <name>/data.pkl                   the pickle (protocol 2) of the object: here a numpy array (pickle.rs)
//! <name>/.format_version            "1"
//! <name>/.storage_alignment         "64"
//! <name>/byteorder                  "little"
//! <name>/version                    "3\n"
//! <name>/.data/serialization_id     40 decimal digits
//! ```
//!
//! The zip layout is the one PyTorch's writer (miniz) produces, checked against `torch.save` 2.13 by
//! tests/python/check_exports.py: each local header has flags 0x0808 (sizes in a data descriptor after
//! the data, UTF-8 names), zero time and date, and an extra field `FB<len>ZZZ…` that pads the record's
//! data to a multiple of 64 bytes; the central directory is followed by a zip64 end record, its locator
//! and the classic end record. The pickle names numpy's `numpy.core.multiarray._reconstruct` (as files
//! saved with numpy 1.x do), which both numpy 1.x and 2.x load; `torch.save` under numpy 2 writes
//! `numpy._core.multiarray`, which numpy before 1.26 cannot load (checked with numpy 1.24.4 and 1.26.4).
//!
//! The serialization id (random in PyTorch) is derived from the pickle's bytes here, so an export is
//! byte-for-byte reproducible.

use super::pickle::{dumps, Value};
use crate::error::{Error, Result};
use crate::geometry::Point;
use std::path::Path;

/// Alignment of every record's data, as PyTorch's writer pads it.
const ALIGNMENT: usize = 64;

/// The `.pth` bytes of a float32 (N, 3) array of `points` saved under the record folder `archive`.
pub fn encode_pth_points(archive: &str, points: &[Point]) -> Vec<u8> {
    let data: Vec<f32> = points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    encode_pth(archive, &Value::ArrayF32 { shape: vec![points.len(), 3], data })
}

/// The `.pth` bytes of `value` (pickled with [`dumps`]) saved under the record folder `archive`.
pub fn encode_pth(archive: &str, value: &Value) -> Vec<u8> {
    let pickle = dumps(value);
    let id = serialization_id(&pickle);
    let mut zip = ZipWriter::default();
    zip.add(&format!("{archive}/data.pkl"), &pickle);
    zip.add(&format!("{archive}/.format_version"), b"1");
    zip.add(&format!("{archive}/.storage_alignment"), ALIGNMENT.to_string().as_bytes());
    zip.add(&format!("{archive}/byteorder"), b"little");
    zip.add(&format!("{archive}/version"), b"3\n");
    zip.add(&format!("{archive}/.data/serialization_id"), id.as_bytes());
    zip.finish()
}

/// The record folder PyTorch names a file's archive after: the file name without its extension.
pub fn archive_name(path: &Path) -> String {
    path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "archive".into())
}

/// Writes `bytes` to `path`, creating parent folders.
pub fn write_pth(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    std::fs::write(path, bytes).map_err(|e| Error::io(path, e))
}

/// 40 decimal digits from the blake3 of the pickle (PyTorch writes 40 digits of its own).
fn serialization_id(pickle: &[u8]) -> String {
    blake3::hash(pickle).as_bytes().iter().take(20).map(|b| format!("{:02}", b % 100)).collect()
}

/// CRC-32 (IEEE 802.3, reflected, polynomial 0xEDB88320), as zip and `zlib.crc32` compute it.
/// (crc32fast is in the dependency tree only indirectly; the table is 1 KiB and built once.)
pub fn crc32(bytes: &[u8]) -> u32 {
    static TABLE: std::sync::OnceLock<[u32; 256]> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let mut t = [0u32; 256];
        for (i, slot) in t.iter_mut().enumerate() {
            let mut c = i as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            }
            *slot = c;
        }
        t
    });
    !bytes.iter().fold(!0u32, |c, &b| table[((c ^ b as u32) & 0xff) as usize] ^ (c >> 8))
}

/// A zip archive of stored records laid out as PyTorch's writer lays them out (see the module docs).
#[derive(Default)]
struct ZipWriter {
    out: Vec<u8>,
    /// (name, crc, size, local header offset)
    entries: Vec<(String, u32, u32, u32)>,
}

impl ZipWriter {
    fn add(&mut self, name: &str, data: &[u8]) {
        let offset = u32::try_from(self.out.len()).expect("a .pth file above 4 GiB needs zip64 records");
        let size = u32::try_from(data.len()).expect("a record above 4 GiB needs zip64 records");
        let crc = crc32(data);
        // Local header (30 bytes), the name, then the extra field `FB` + u16 length + 'Z' padding, so
        // that the data starts at a multiple of ALIGNMENT.
        let start = self.out.len() + 30 + name.len() + 4;
        let padding = (ALIGNMENT - start % ALIGNMENT) % ALIGNMENT;
        let o = &mut self.out;
        o.extend_from_slice(&0x0403_4b50u32.to_le_bytes());
        o.extend_from_slice(&0u16.to_le_bytes()); // version needed (as PyTorch's writer)
        o.extend_from_slice(&0x0808u16.to_le_bytes()); // data descriptor, UTF-8 name
        o.extend_from_slice(&0u16.to_le_bytes()); // stored
        o.extend_from_slice(&[0; 4]); // time, date
        o.extend_from_slice(&[0; 12]); // crc, sizes: in the data descriptor
        o.extend_from_slice(&(name.len() as u16).to_le_bytes());
        o.extend_from_slice(&((padding + 4) as u16).to_le_bytes());
        o.extend_from_slice(name.as_bytes());
        o.extend_from_slice(b"FB");
        o.extend_from_slice(&(padding as u16).to_le_bytes());
        o.resize(o.len() + padding, b'Z');
        debug_assert_eq!(o.len() % ALIGNMENT, 0);
        o.extend_from_slice(data);
        o.extend_from_slice(&0x0807_4b50u32.to_le_bytes());
        o.extend_from_slice(&crc.to_le_bytes());
        o.extend_from_slice(&size.to_le_bytes());
        o.extend_from_slice(&size.to_le_bytes());
        self.entries.push((name.to_string(), crc, size, offset));
    }

    fn finish(mut self) -> Vec<u8> {
        let cd_offset = self.out.len();
        let o = &mut self.out;
        for (name, crc, size, offset) in &self.entries {
            o.extend_from_slice(&0x0201_4b50u32.to_le_bytes());
            o.extend_from_slice(&0u16.to_le_bytes()); // version made by
            o.extend_from_slice(&0u16.to_le_bytes()); // version needed
            o.extend_from_slice(&0x0808u16.to_le_bytes());
            o.extend_from_slice(&0u16.to_le_bytes()); // stored
            o.extend_from_slice(&[0; 4]); // time, date
            o.extend_from_slice(&crc.to_le_bytes());
            o.extend_from_slice(&size.to_le_bytes());
            o.extend_from_slice(&size.to_le_bytes());
            o.extend_from_slice(&(name.len() as u16).to_le_bytes());
            o.extend_from_slice(&[0; 12]); // extra, comment, disk, internal and external attributes
            o.extend_from_slice(&offset.to_le_bytes());
            o.extend_from_slice(name.as_bytes());
        }
        let n = self.entries.len() as u64;
        let cd_size = (o.len() - cd_offset) as u64;
        let zip64_offset = o.len() as u64;
        // Zip64 end of central directory record and its locator, then the classic end record.
        o.extend_from_slice(&0x0606_4b50u32.to_le_bytes());
        o.extend_from_slice(&44u64.to_le_bytes());
        o.extend_from_slice(&0x031eu16.to_le_bytes()); // made by: Unix, 3.0
        o.extend_from_slice(&0x002du16.to_le_bytes()); // needed: 4.5 (zip64)
        o.extend_from_slice(&[0; 8]); // this disk, disk of the central directory
        o.extend_from_slice(&n.to_le_bytes());
        o.extend_from_slice(&n.to_le_bytes());
        o.extend_from_slice(&cd_size.to_le_bytes());
        o.extend_from_slice(&(cd_offset as u64).to_le_bytes());
        o.extend_from_slice(&0x0706_4b50u32.to_le_bytes());
        o.extend_from_slice(&0u32.to_le_bytes());
        o.extend_from_slice(&zip64_offset.to_le_bytes());
        o.extend_from_slice(&1u32.to_le_bytes());
        o.extend_from_slice(&0x0605_4b50u32.to_le_bytes());
        o.extend_from_slice(&[0; 4]); // this disk, disk of the central directory
        o.extend_from_slice(&(n as u16).to_le_bytes());
        o.extend_from_slice(&(n as u16).to_le_bytes());
        o.extend_from_slice(&(cd_size as u32).to_le_bytes());
        o.extend_from_slice(&(cd_offset as u32).to_le_bytes());
        o.extend_from_slice(&0u16.to_le_bytes()); // comment
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_matches_the_standard_check_values() {
        assert_eq!(crc32(b""), 0);
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        // zlib.crc32(b"little") and zlib.crc32(b"3\n"), the records PyTorch writes (their CRCs in a torch.save file).
        assert_eq!(crc32(b"little"), 0x19e3_3d85);
        assert_eq!(crc32(b"3\n"), 0x5567_9ed1);
        assert_eq!(crc32(b"1"), 0x83dc_efb7);
        assert_eq!(crc32(b"64"), 0xe971_773f);
    }

    /// The little-endian u16/u32 at `at`.
    fn u16_at(b: &[u8], at: usize) -> usize {
        u16::from_le_bytes([b[at], b[at + 1]]) as usize
    }
    fn u32_at(b: &[u8], at: usize) -> usize {
        u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize
    }

    #[test]
    fn records_are_aligned_and_the_directories_point_at_them() {
        let pts = vec![Point::new(1.0, 2.0, 3.0), Point::new(-0.5, 0.25, 8.0)];
        let b = encode_pth_points("cloud_bin_0", &pts);
        assert_eq!(&b[..4], b"PK\x03\x04");
        // The classic end record: 6 entries, the central directory's size and offset.
        let end = b.len() - 22;
        assert_eq!(u32_at(&b, end), 0x0605_4b50);
        assert_eq!((u16_at(&b, end + 8), u16_at(&b, end + 10)), (6, 6));
        let (cd_size, mut at) = (u32_at(&b, end + 12), u32_at(&b, end + 16));
        assert_eq!(u32_at(&b, end - 20), 0x0706_4b50, "zip64 locator");
        assert_eq!(u32_at(&b, end - 20 + 8), at + cd_size, "the locator points at the zip64 end record");
        let mut names = Vec::new();
        for _ in 0..6 {
            assert_eq!(u32_at(&b, at), 0x0201_4b50);
            let (crc, size, name_len, local) = (u32_at(&b, at + 16), u32_at(&b, at + 20), u16_at(&b, at + 28), u32_at(&b, at + 42));
            let name = std::str::from_utf8(&b[at + 46..at + 46 + name_len]).unwrap().to_string();
            assert_eq!(u32_at(&b, local), 0x0403_4b50);
            assert_eq!(&b[local + 30..local + 30 + name_len], name.as_bytes());
            let data = local + 30 + name_len + u16_at(&b, local + 28);
            assert_eq!(data % ALIGNMENT, 0, "{name}: data at {data}");
            assert_eq!(&b[local + 30 + name_len..local + 32 + name_len], b"FB");
            assert_eq!(crc32(&b[data..data + size]), crc as u32, "{name}");
            assert_eq!(u32_at(&b, data + size), 0x0807_4b50, "{name}: data descriptor");
            if name.ends_with("/version") {
                assert_eq!(&b[data..data + size], b"3\n");
            }
            if name.ends_with("/data.pkl") {
                let values = vec![1.0, 2.0, 3.0, -0.5, 0.25, 8.0];
                assert_eq!(&b[data..data + size], &dumps(&Value::ArrayF32 { shape: vec![2, 3], data: values })[..]);
            }
            names.push(name);
            at += 46 + name_len;
        }
        assert_eq!(
            names,
            ["data.pkl", ".format_version", ".storage_alignment", "byteorder", "version", ".data/serialization_id"].map(|n| format!("cloud_bin_0/{n}"))
        );
        // Deterministic: the same cloud gives the same bytes.
        assert_eq!(encode_pth_points("cloud_bin_0", &pts), b);
        assert_eq!(archive_name(Path::new("/x/train/s/cloud_bin_12.pth")), "cloud_bin_12");
    }
}
