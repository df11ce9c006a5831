//! Records of what a run read and how long it took: files by path and sha256, and
//! wall-clock time per stage (run.json's parts that every stage may fill in).

use std::io::Read;
use std::path::Path;
use std::time::Instant;

use sha2::{Digest, Sha256};

/// A file by path and sha256.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct FileRecord {
    pub path: String,
    pub sha256: String,
}

impl FileRecord {
    pub fn of(path: &Path) -> std::io::Result<Self> {
        Ok(Self {
            path: path.display().to_string(),
            sha256: sha256_file(path)?,
        })
    }
}

pub fn sha256_file(path: &Path) -> std::io::Result<String> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(crate::io::limits::not_a_regular_file(&meta));
    }
    let mut file = std::fs::File::open(path)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// Wall-clock time per stage, in the order stages first ran; repeated stages add up.
#[derive(Debug, Default)]
pub struct Timings {
    stages: Vec<(String, f64)>,
}

impl Timings {
    pub fn time<T>(&mut self, stage: &str, f: impl FnOnce() -> T) -> T {
        let start = Instant::now();
        let result = f();
        self.add(stage, start.elapsed().as_secs_f64() * 1e3);
        result
    }

    pub fn add(&mut self, stage: &str, ms: f64) {
        match self.stages.iter_mut().find(|(s, _)| s == stage) {
            Some((_, total)) => *total += ms,
            None => self.stages.push((stage.into(), ms)),
        }
    }

    pub fn stages(&self) -> &[(String, f64)] {
        &self.stages
    }

    /// The time of `stage` so far (0 if it has not run).
    pub fn ms(&self, stage: &str) -> f64 {
        self.stages
            .iter()
            .find(|(s, _)| s == stage)
            .map_or(0.0, |(_, ms)| *ms)
    }
}

/// A JSON object in stage order.
impl serde::Serialize for Timings {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = serializer.serialize_map(Some(self.stages.len()))?;
        for (stage, ms) in &self.stages {
            map.serialize_entry(stage, &((ms * 1000.0).round() / 1000.0))?;
        }
        map.end()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sha256_matches_known_digest() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("abc");
        std::fs::write(&path, b"abc").unwrap();
        assert_eq!(
            sha256_file(&path).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn repeated_stages_accumulate_in_first_seen_order() {
        let mut t = Timings::default();
        t.add("a", 1.0);
        t.add("b", 2.0);
        t.add("a", 3.0);
        assert_eq!(t.stages(), [("a".into(), 4.0), ("b".into(), 2.0)]);
        assert_eq!((t.ms("a"), t.ms("c")), (4.0, 0.0));
        assert_eq!(serde_json::to_string(&t).unwrap(), r#"{"a":4.0,"b":2.0}"#);
    }
}
