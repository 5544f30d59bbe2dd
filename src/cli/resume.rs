//! `verify --checkpoint` / `--resume` and interrupts: the run's identity (what its verdicts
//! depend on), the checkpoint file, and a SIGINT/SIGTERM handler that lets the current chunk
//! finish so that the checkpoint keeps it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use cbfreach::provenance::{filter_hash, network_hash, region_hash, Fnv};
use cbfreach::reach::{ReachProblem, ReachSettings};
use cbfreach::scenario::Scenario;
use cbfreach::verify::checkpoint::Checkpoint;
use cbfreach::verify::VerifySettings;

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
) -> Result<Checkpoint, Box<dyn std::error::Error>> {
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
