//! `verify --checkpoint` / `--resume`, `paper --resume`, and interrupts: the run's identity (what its verdicts
//! depend on), the checkpoint file, and a SIGINT/SIGTERM handler that lets the current chunk
//! finish so that the checkpoint keeps it.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use cbfreach::provenance::{filter_hash, network_hash, region_hash, Fnv};
use cbfreach::reach::{ReachProblem, ReachSettings};
use cbfreach::scenario::Scenario;
use cbfreach::verify::checkpoint::{Checkpoint, Journal};
use cbfreach::verify::{VerifyError, VerifySettings};

/// Set by the first SIGINT or SIGTERM; a second one ends the process at once.
static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    if STOP.swap(true, Ordering::SeqCst) {
        // SAFETY: `_exit` is async-signal-safe.
        unsafe { libc::_exit(130) }
    }
}

/// Installs the handler: the run stops after its current chunk (see [`Checkpoint::stop_on`]).
pub fn stop_on_interrupt() -> &'static AtomicBool {
    // SAFETY: the handler only touches an atomic and calls `_exit`, both async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
    &STOP
}

/// What a verification's verdicts depend on, by name: the network file, the filter, the
/// region `C`, the error map's cells (local margins), and the settings.
pub fn identity(
    s: &Scenario,
    problem: &ReachProblem,
    network: &Path,
    settings: &VerifySettings,
    reach: &ReachSettings,
) -> std::io::Result<BTreeMap<String, String>> {
    let mut id = BTreeMap::new();
    id.insert("network".into(), network_hash(network)?);
    id.insert("filter".into(), filter_hash(s));
    id.insert("region C".into(), region_hash(&s.reach.region));
    id.insert(
        "error map".into(),
        problem
            .error_map
            .as_ref()
            .map_or("none".into(), |m| m.cells_digest()),
    );
    let run = format!(
        "{settings:?}|{reach:?}|{:?}|{}|{}|{}|{}|{}|{:?}",
        problem.m_c.to_bits(),
        problem.dt.to_bits(),
        problem.steps,
        problem.time,
        problem.steps_per_dt(),
        problem.transform.is_some(),
        s.reach.goal
    );
    id.insert("settings".into(), Fnv::default().str(&run).hex());
    Ok(id)
}

/// The checkpoint file: `--checkpoint`, else `<--json>.checkpoint`, else none.
pub fn checkpoint_path(given: Option<&Path>, json: Option<&Path>) -> Option<PathBuf> {
    given.map(Path::to_path_buf).or_else(|| {
        json.map(|j| {
            let mut name = j.as_os_str().to_owned();
            name.push(".checkpoint");
            PathBuf::from(name)
        })
    })
}

/// Opens (with `resume`) or creates the checkpoint and makes interrupts stop at a chunk's end.
pub fn open(
    path: &Path,
    resume: bool,
    identity: BTreeMap<String, String>,
) -> Result<Checkpoint, VerifyError> {
    let c = if resume {
        let c = Checkpoint::resume(path, identity)?;
        eprintln!(
            "resuming from {}: {} boxes already done",
            path.display(),
            c.recorded()
        );
        c
    } else {
        Checkpoint::create(path, identity)?
    };
    Ok(c.stop_on(stop_on_interrupt()))
}

/// The checkpoints of `paper`'s split boxes: a file a box in the output folder
/// (`<scenario>-box<k>.checkpoint`), kept until the whole run ends so that `paper --resume`
/// continues an interrupted run; [`PiecesCheckpoints::finish`] removes them.
pub struct PiecesCheckpoints {
    folder: PathBuf,
    resume: bool,
    made: RefCell<Vec<PathBuf>>,
}

impl PiecesCheckpoints {
    /// The checkpoints of scenarios `names` in `folder`. Without `resume`, refused when one is
    /// there (an interrupted run's work, before any of this run's is done).
    pub fn new(folder: &Path, resume: bool, names: &[&str]) -> Result<Self, String> {
        let this = PiecesCheckpoints {
            folder: folder.to_path_buf(),
            resume,
            made: RefCell::new(Vec::new()),
        };
        if !resume {
            let entries =
                std::fs::read_dir(folder).map_err(|e| format!("{}: {e}", folder.display()))?;
            for entry in entries.flatten() {
                let name = entry.file_name().to_string_lossy().into_owned();
                if names.iter().any(|s| is_checkpoint_of(s, &name)) {
                    return Err(format!(
                        "{}: exists (an interrupted run?): give --resume to continue it, or remove it",
                        entry.path().display()
                    ));
                }
            }
        }
        Ok(this)
    }

    /// Initial box `k`'s journal (numbered from 1 in the file name, as printed), whose pieces
    /// run as `settings`: resumed where an earlier run left it, else new; interrupts stop the
    /// run after a chunk.
    pub fn journal(
        &self,
        s: &Scenario,
        problem: &ReachProblem,
        network: &Path,
        settings: &VerifySettings,
        reach: &ReachSettings,
        k: usize,
    ) -> Result<Box<dyn Journal>, VerifyError> {
        let path = self.folder.join(checkpoint_name(&s.name, k));
        let identity =
            identity(s, problem, network, settings, reach).map_err(|e| VerifyError::Format {
                file: network.display().to_string(),
                message: e.to_string(),
            })?;
        let c = open(&path, self.resume && path.exists(), identity)?;
        self.made.borrow_mut().push(path);
        Ok(Box::new(c))
    }

    /// Removes the checkpoints (the run finished and its verdicts are printed).
    pub fn finish(self) -> std::io::Result<()> {
        for path in self.made.into_inner() {
            std::fs::remove_file(path)?;
        }
        Ok(())
    }
}

/// Initial box `k`'s checkpoint file in a `paper` run (numbered from 1, as printed).
fn checkpoint_name(scenario: &str, k: usize) -> String {
    format!("{scenario}-box{:02}.checkpoint", k + 1)
}

/// Whether `file` is a name [`checkpoint_name`] gives for `scenario`.
fn is_checkpoint_of(scenario: &str, file: &str) -> bool {
    file.strip_prefix(scenario)
        .and_then(|rest| rest.strip_prefix("-box"))
        .and_then(|rest| rest.strip_suffix(".checkpoint"))
        .is_some_and(|k| !k.is_empty() && k.bytes().all(|b| b.is_ascii_digit()))
}
