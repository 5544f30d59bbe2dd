//! Checkpoints of a verification: every chunk of boxes the engine finishes is appended to a
//! file with the run's identity (hashes of the network, filter, region and settings), so that
//! an interrupted run (`SIGINT`, a crash, a full disk) resumes where it stopped and ends in the
//! report an uninterrupted run gives. A [`Journal`] is what the verifier asks; [`Checkpoint`]
//! is the file. May import `verify`'s report types.

use std::collections::{BTreeMap, HashMap};
use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use super::{BoxVerdict, Verdict, VerifyError};
use crate::boxes::IntervalBox;

/// What the verifier asks of a checkpoint while it runs.
pub trait Journal: Sync {
    /// The recorded verdict of a box (grid cell `cell`, `depth` bisections), with the steps
    /// its tube ran, if an earlier run finished it.
    fn lookup(&self, cell: usize, depth: usize, b: &IntervalBox) -> Option<(BoxVerdict, usize)>;
    /// Records finished boxes with their steps (durably, before the next chunk starts).
    fn record(&self, done: &[(BoxVerdict, usize)]) -> Result<(), VerifyError>;
    /// Whether the run should stop after the chunk it finished (an interrupt).
    fn stop_requested(&self) -> bool;
}

/// No checkpoint: nothing recorded, never stops.
pub struct NoJournal;

impl Journal for NoJournal {
    fn lookup(&self, _: usize, _: usize, _: &IntervalBox) -> Option<(BoxVerdict, usize)> {
        None
    }
    fn record(&self, _: &[(BoxVerdict, usize)]) -> Result<(), VerifyError> {
        Ok(())
    }
    fn stop_requested(&self) -> bool {
        false
    }
}

/// Format tag of checkpoint files (their first line).
pub const CHECKPOINT_FORMAT: &str = "cbfreach-verify-checkpoint-1";

/// The first line: what the run was.
#[derive(Serialize, Deserialize)]
struct Header {
    format: String,
    /// Named hashes of what the verdicts depend on (network, filter, region, settings, …).
    identity: BTreeMap<String, String>,
}

/// One finished box; numbers by their bits, so that a resumed report is bit-identical.
#[derive(Serialize, Deserialize)]
struct Entry {
    cell: usize,
    depth: usize,
    lower: Vec<u64>,
    upper: Vec<u64>,
    verdict: Verdict,
    #[serde(default)]
    final_set: Option<(Vec<u64>, Vec<u64>)>,
    #[serde(default)]
    t_end: Option<u64>,
    #[serde(default)]
    trap: Option<usize>,
    #[serde(default)]
    note: Option<String>,
    #[serde(default)]
    ended: Option<crate::reach::EndKind>,
    #[serde(default)]
    feasible: Option<bool>,
    steps: usize,
}

type Key = (usize, usize, Vec<u64>, Vec<u64>);

fn bits(x: &[f64]) -> Vec<u64> {
    x.iter().map(|v| v.to_bits()).collect()
}

fn unbits(x: &[u64]) -> Vec<f64> {
    x.iter().map(|&v| f64::from_bits(v)).collect()
}

impl Entry {
    fn of(b: &BoxVerdict, steps: usize) -> Entry {
        Entry {
            cell: b.cell,
            depth: b.depth,
            lower: bits(&b.initial.lower),
            upper: bits(&b.initial.upper),
            verdict: b.verdict,
            final_set: b
                .final_set
                .as_ref()
                .map(|s| (bits(&s.lower), bits(&s.upper))),
            t_end: b.t_end.map(f64::to_bits),
            trap: b.trap,
            note: b.note.clone(),
            ended: b.ended,
            feasible: b.feasible,
            steps,
        }
    }

    fn key(&self) -> Key {
        (
            self.cell,
            self.depth,
            self.lower.clone(),
            self.upper.clone(),
        )
    }

    fn verdict(&self) -> (BoxVerdict, usize) {
        let v = BoxVerdict {
            cell: self.cell,
            depth: self.depth,
            initial: IntervalBox {
                lower: unbits(&self.lower),
                upper: unbits(&self.upper),
            },
            verdict: self.verdict,
            final_set: self.final_set.as_ref().map(|(l, u)| IntervalBox {
                lower: unbits(l),
                upper: unbits(u),
            }),
            t_end: self.t_end.map(f64::from_bits),
            trap: self.trap,
            note: self.note.clone(),
            ended: self.ended,
            feasible: self.feasible,
        };
        (v, self.steps)
    }
}

/// A checkpoint file: appended to as chunks finish, read back by `resume`.
pub struct Checkpoint {
    path: PathBuf,
    file: Mutex<std::fs::File>,
    done: HashMap<Key, Entry>,
    stop: Option<&'static AtomicBool>,
}

impl Checkpoint {
    /// Starts a fresh checkpoint at `path` for a run of this identity (refused when a file is
    /// there: it may hold an interrupted run's work; resume it or remove it).
    pub fn create(
        path: &Path,
        identity: BTreeMap<String, String>,
    ) -> Result<Checkpoint, VerifyError> {
        let io = |e: std::io::Error| checkpoint_error(path, e.to_string());
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::AlreadyExists => checkpoint_error(
                    path,
                    "exists (an interrupted run?): give --resume to continue it, or remove it"
                        .into(),
                ),
                _ => io(e),
            })?;
        let header = Header {
            format: CHECKPOINT_FORMAT.into(),
            identity,
        };
        writeln!(file, "{}", to_line(&header)?).map_err(io)?;
        file.sync_data().map_err(io)?;
        Ok(Checkpoint {
            path: path.to_path_buf(),
            file: Mutex::new(file),
            done: HashMap::new(),
            stop: None,
        })
    }

    /// Opens the checkpoint of an interrupted run with this identity; refused, naming what
    /// differs, when it was another run. A last line cut short (a crash mid-write) is dropped.
    pub fn resume(
        path: &Path,
        identity: BTreeMap<String, String>,
    ) -> Result<Checkpoint, VerifyError> {
        let io = |e: std::io::Error| checkpoint_error(path, e.to_string());
        let file = std::fs::File::open(path).map_err(io)?;
        let mut lines = std::io::BufReader::new(file).lines();
        let first = lines
            .next()
            .transpose()
            .map_err(io)?
            .ok_or_else(|| checkpoint_error(path, "is empty".into()))?;
        let header: Header = serde_json::from_str(&first)
            .map_err(|e| checkpoint_error(path, format!("not a checkpoint: {e}")))?;
        if header.format != CHECKPOINT_FORMAT {
            return Err(checkpoint_error(
                path,
                format!("format `{}`, expected `{CHECKPOINT_FORMAT}`", header.format),
            ));
        }
        let changed: std::collections::BTreeSet<&str> = identity
            .keys()
            .chain(header.identity.keys())
            .filter(|k| identity.get(*k) != header.identity.get(*k))
            .map(String::as_str)
            .collect();
        if !changed.is_empty() {
            let changed: Vec<&str> = changed.into_iter().collect();
            return Err(checkpoint_error(
                path,
                format!(
                    "was written by another run ({} changed); remove it to start afresh",
                    changed.join(", ")
                ),
            ));
        }
        let mut valid_len = first.len() as u64 + 1;
        let mut done = HashMap::new();
        for line in lines {
            let Ok(line) = line else { break };
            match serde_json::from_str::<Entry>(&line) {
                Ok(e) => {
                    valid_len += line.len() as u64 + 1;
                    done.insert(e.key(), e);
                }
                // A line cut short by a crash: drop it and what follows.
                Err(_) => break,
            }
        }
        let file = std::fs::OpenOptions::new()
            .write(true)
            .open(path)
            .map_err(io)?;
        file.set_len(valid_len).map_err(io)?;
        let mut file = file;
        std::io::Seek::seek(&mut file, std::io::SeekFrom::End(0)).map_err(io)?;
        Ok(Checkpoint {
            path: path.to_path_buf(),
            file: Mutex::new(file),
            done,
            stop: None,
        })
    }

    /// Stops the run after the chunk it is in when `flag` is set (by a signal handler).
    pub fn stop_on(mut self, flag: &'static AtomicBool) -> Checkpoint {
        self.stop = Some(flag);
        self
    }

    /// Boxes recorded so far (read at `resume`).
    pub fn recorded(&self) -> usize {
        self.done.len()
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Removes the file (the run finished and its report is written).
    pub fn finish(self) -> std::io::Result<()> {
        std::fs::remove_file(&self.path)
    }
}

fn checkpoint_error(path: &Path, message: String) -> VerifyError {
    VerifyError::Format {
        file: path.display().to_string(),
        message,
    }
}

fn to_line<T: Serialize>(v: &T) -> Result<String, VerifyError> {
    serde_json::to_string(v).map_err(|e| VerifyError::Format {
        file: "<checkpoint>".into(),
        message: e.to_string(),
    })
}

impl Journal for Checkpoint {
    fn lookup(&self, cell: usize, depth: usize, b: &IntervalBox) -> Option<(BoxVerdict, usize)> {
        self.done
            .get(&(cell, depth, bits(&b.lower), bits(&b.upper)))
            .map(Entry::verdict)
    }

    fn record(&self, done: &[(BoxVerdict, usize)]) -> Result<(), VerifyError> {
        let mut text = String::new();
        for (b, steps) in done {
            text.push_str(&to_line(&Entry::of(b, *steps))?);
            text.push('\n');
        }
        let mut file = self
            .file
            .lock()
            .map_err(|_| checkpoint_error(&self.path, "poisoned".into()))?;
        let io = |e: std::io::Error| checkpoint_error(&self.path, e.to_string());
        file.write_all(text.as_bytes()).map_err(io)?;
        file.sync_data().map_err(io)
    }

    fn stop_requested(&self) -> bool {
        self.stop.is_some_and(|f| f.load(Ordering::SeqCst))
    }
}
