//! Helpers shared by the integration tests.

use std::path::{Path, PathBuf};

/// The shared read-only data folder (`$G1VIZ_SHARED`, else `<crate>/../shared`), or `None` with a
/// note on stderr so the caller can skip.
pub fn shared_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("G1VIZ_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"));
    if dir.join("recordings").is_dir() {
        Some(dir)
    } else {
        skip(&format!(
            "shared data not found at {} (set G1VIZ_SHARED)",
            dir.display()
        ));
        None
    }
}

/// Note on stderr that a test (or part of it) is skipped because something outside the crate is
/// missing — the shared data, python3 with its packages, the stock `rerun` CLI. With
/// `G1VIZ_REQUIRE_ALL=1` (set by `.ci/run`, which installs all of it) a skip is a failure, so a
/// missing install step cannot turn into a green run that checked nothing.
pub fn skip(reason: &str) {
    if std::env::var_os("G1VIZ_REQUIRE_ALL").is_some_and(|v| !v.is_empty() && v != "0") {
        panic!("G1VIZ_REQUIRE_ALL is set but a check would be skipped: {reason}");
    }
    eprintln!("note: skipping: {reason}");
}

/// A file under the shared `recordings/` folder, if the folder is there.
#[allow(dead_code)] // not every test binary uses every helper
pub fn shared_recording(name: &str) -> Option<PathBuf> {
    let path = shared_dir()?.join("recordings").join(name);
    if path.exists() {
        Some(path)
    } else {
        skip(&format!("{} not found", path.display()));
        None
    }
}

// ------------------------------------------------------------------ external processes

/// Time limit for a run of the `g1viz` binary (the slowest, a full workflow step in the dev
/// profile on a loaded 2-core machine, takes about a minute).
#[allow(dead_code)]
pub const G1VIZ_LIMIT: std::time::Duration = std::time::Duration::from_secs(15 * 60);

/// Time limit for a python check or the stock `rerun` CLI.
#[allow(dead_code)]
pub const TOOL_LIMIT: std::time::Duration = std::time::Duration::from_secs(5 * 60);

/// A child process in a process group of its own; dropping it kills the whole group, so nothing
/// a test starts outlives the test, even when the test panics.
#[allow(dead_code)]
pub struct Group {
    child: std::process::Child,
    what: String,
}

#[allow(dead_code)]
impl Group {
    /// Spawn `cmd` as the leader of a new process group. SIGINT and SIGQUIT are set back to their
    /// default action in the child: a shell starts background jobs with them ignored, and an
    /// ignored SIGINT is inherited through `exec` (the stock `rerun` Python wrapper then never
    /// exits).
    pub fn spawn(cmd: &mut std::process::Command) -> std::io::Result<Group> {
        use std::os::unix::process::CommandExt;
        let what = format!("{:?}", cmd);
        cmd.process_group(0);
        // SAFETY: signal(2) is async-signal-safe; nothing else runs between fork and exec.
        unsafe {
            cmd.pre_exec(|| {
                libc::signal(libc::SIGINT, libc::SIG_DFL);
                libc::signal(libc::SIGQUIT, libc::SIG_DFL);
                Ok(())
            });
        }
        let child = cmd.spawn()?;
        Ok(Group { child, what })
    }

    /// The process id of the group leader (= the group id).
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// The leader has exited (not yet reaped: the group id stays reserved until it is).
    fn leader_exited(&self) -> bool {
        // SAFETY: waitid on our own child with WNOWAIT only inspects its state.
        unsafe {
            let mut info: libc::siginfo_t = std::mem::zeroed();
            libc::waitid(
                libc::P_PID,
                self.child.id() as libc::id_t,
                &mut info,
                libc::WEXITED | libc::WNOHANG | libc::WNOWAIT,
            ) == 0
                && info.si_pid() != 0
        }
    }

    /// Send `signal` to every process of the group.
    fn signal(&self, signal: libc::c_int) {
        // SAFETY: kill(2) of the process group we created; the leader is not reaped yet, so the
        // group id cannot have been reused.
        unsafe {
            libc::kill(-(self.child.id() as libc::pid_t), signal);
        }
    }

    /// Wait up to `limit` for the leader to exit; true when it did.
    fn wait_exit(&self, limit: std::time::Duration) -> bool {
        let deadline = std::time::Instant::now() + limit;
        loop {
            if self.leader_exited() {
                return true;
            }
            if std::time::Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    /// Kill what is left of the group and reap the leader.
    fn finish(&mut self) -> std::process::ExitStatus {
        self.signal(libc::SIGKILL);
        self.child.wait().expect("reap child")
    }

    /// Stop the group politely and then firmly, each step with a bounded wait: SIGINT (lets a
    /// server finish its output), SIGTERM after `grace`, SIGKILL 5 s later. Returns the
    /// leader's exit status.
    pub fn stop(mut self, grace: std::time::Duration) -> std::process::ExitStatus {
        for (signal, wait) in [
            (libc::SIGINT, grace),
            (libc::SIGTERM, std::time::Duration::from_secs(5)),
        ] {
            self.signal(signal);
            if self.wait_exit(wait) {
                break;
            }
            eprintln!("note: {} did not stop on signal {signal}", self.what);
        }
        self.finish()
    }

    /// Wait up to `limit` for the leader to exit; then kill the rest of the group. `None` (and
    /// the whole group killed) when the limit passed first.
    pub fn wait_within(&mut self, limit: std::time::Duration) -> Option<std::process::ExitStatus> {
        let exited = self.wait_exit(limit);
        if !exited {
            self.signal(libc::SIGTERM);
            self.wait_exit(std::time::Duration::from_secs(5));
        }
        let status = self.finish();
        exited.then_some(status)
    }
}

impl Drop for Group {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.signal(libc::SIGKILL);
            let _ = self.child.wait();
        }
    }
}

/// `cmd.output()` with a time limit: the command runs in its own process group with stdin from
/// /dev/null; when it has not finished within `limit` the whole group is killed and the test
/// panics naming the command. `Err` only when the program cannot be started (not installed), so
/// callers can skip.
#[allow(dead_code)]
pub fn output_within(
    cmd: &mut std::process::Command,
    limit: std::time::Duration,
) -> std::io::Result<std::process::Output> {
    use std::io::Read;
    use std::process::Stdio;
    cmd.stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let mut group = Group::spawn(cmd)?;
    let drain = |pipe: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            if let Some(mut p) = pipe {
                let _ = p.read_to_end(&mut buf);
            }
            buf
        })
    };
    let stdout = drain(group.child.stdout.take().map(|p| Box::new(p) as _));
    let stderr = drain(group.child.stderr.take().map(|p| Box::new(p) as _));
    let status = group.wait_within(limit);
    // Every process of the group is gone now, so the pipes are closed and the readers finish.
    let (stdout, stderr) = (stdout.join().unwrap(), stderr.join().unwrap());
    let Some(status) = status else {
        panic!(
            "{} did not finish within {limit:?}; its process group was killed. stderr:\n{}",
            group.what,
            String::from_utf8_lossy(&stderr)
        );
    };
    Ok(std::process::Output {
        status,
        stdout,
        stderr,
    })
}

// ------------------------------------------------------------------ documented figures

/// The text of a documentation page, by its path in the crate (`README.md`, `docs/model.md`).
#[allow(dead_code)]
#[track_caller]
pub fn doc_page(page: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(page);
    std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("documentation page {}: {e}", path.display()))
}

/// The fenced code blocks of `page` whose opening fence names `lang` (```` ```sh ````), in order,
/// each as its lines.
#[allow(dead_code)]
pub fn doc_blocks(page: &str, lang: &str) -> Vec<Vec<String>> {
    let mut blocks = Vec::new();
    let mut current: Option<(bool, Vec<String>)> = None;
    for line in doc_page(page).lines() {
        if let Some(fence) = line.strip_prefix("```") {
            match current.take() {
                Some((true, b)) => blocks.push(b),
                Some((false, _)) => {}
                None => current = Some((fence.trim() == lang, Vec::new())),
            }
        } else if let Some((_, b)) = current.as_mut() {
            b.push(line.to_owned());
        }
    }
    blocks
}

/// Assert that `got` is the figure `page` prints as `stated`, at the precision it is printed
/// with: within half a unit of its last digit ("0.998" → ± 0.0005, "0.34" → ± 0.005, "2.5e8" →
/// ± 0.05e8, "53" → ± 0.5) — and that the page prints `stated` (as a number of its own, a
/// typographic minus read as `-`), so a figure changed on the page fails its test too.
#[allow(dead_code)]
#[track_caller]
pub fn assert_figure(page: &str, what: &str, got: f64, stated: &str) {
    let text = doc_page(page).replace('−', "-");
    let number_char = |c: Option<char>| c.is_some_and(|c| c.is_ascii_digit() || c == '.');
    let printed = text.match_indices(stated).any(|(at, _)| {
        let before = text[..at].chars().next_back();
        let mut after = text[at + stated.len()..].chars();
        // "0.3" is not printed by "0.35", nor by "10.3"; "0.3." (a sentence's end) is.
        let ends_there = match after.next() {
            Some(c) if c.is_ascii_digit() => false,
            Some('.') => !number_char(after.next()),
            _ => true,
        };
        !number_char(before) && ends_there
    });
    assert!(printed, "{what}: {page} does not print {stated}");
    let (mantissa, exponent) = match stated.split_once(['e', 'E']) {
        Some((m, e)) => (m, e.parse::<i32>().expect("exponent")),
        None => (stated, 0),
    };
    let decimals = mantissa.split_once('.').map_or(0, |(_, d)| d.len()) as i32;
    let value: f64 = stated.parse().expect("a number");
    let tolerance = 0.5 * 10f64.powi(exponent - decimals);
    assert!(
        (got - value).abs() <= tolerance * (1.0 + 1e-9),
        "{what}: {got} is not {page}'s {stated} (± {tolerance:e})"
    );
    eprintln!("{what}: {got} = {page} {stated} ± {tolerance:e}");
}

/// Whether python3 can import `module`; when it cannot, a skip note naming the pip package.
#[allow(dead_code)]
pub fn python_module(module: &str, pip: &str) -> bool {
    let ok = output_within(
        std::process::Command::new("python3").args(["-c", &format!("import {module}")]),
        TOOL_LIMIT,
    )
    .is_ok_and(|o| o.status.success());
    if !ok {
        skip(&format!(
            "python3 `{module}` not importable (pip install {pip})"
        ));
    }
    ok
}

// ------------------------------------------------------------------ MCAP files written by tests

/// One message of an MCAP file as the `mcap` crate reads it: topic, schema (name, encoding,
/// text), log time and CDR payload.
#[allow(dead_code)]
pub struct McapMsg {
    /// Channel topic.
    pub topic: String,
    /// Schema name, encoding and data.
    pub schema: (String, String, Vec<u8>),
    /// Log time [ns].
    pub log_time: u64,
    /// Payload.
    pub data: Vec<u8>,
}

/// The messages of the shipped `examples/g1_example.mcap`, in file order.
#[allow(dead_code)]
pub fn example_messages() -> Vec<McapMsg> {
    let bytes =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap"))
            .unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            let s = m.channel.schema.as_ref().unwrap();
            McapMsg {
                topic: m.channel.topic.clone(),
                schema: (s.name.clone(), s.encoding.clone(), s.data.to_vec()),
                log_time: m.log_time,
                data: m.data.to_vec(),
            }
        })
        .collect()
}

/// Writes `msgs` through `w` (one `cdr` channel per topic, with its schema; sequence = index;
/// publish time = log time); returns the bytes they take in a chunk (payload + 31-byte record).
#[allow(dead_code)]
pub fn write_messages<W: std::io::Write + std::io::Seek>(
    w: &mut mcap::Writer<W>,
    msgs: &[McapMsg],
) -> usize {
    let mut channels = std::collections::BTreeMap::<String, u16>::new();
    let mut written = 0;
    for (seq, m) in msgs.iter().enumerate() {
        let id = *channels.entry(m.topic.clone()).or_insert_with(|| {
            let sid = w.add_schema(&m.schema.0, &m.schema.1, &m.schema.2).unwrap();
            w.add_channel(sid, &m.topic, "cdr", &std::collections::BTreeMap::new())
                .unwrap()
        });
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: seq as u32,
            log_time: m.log_time,
            publish_time: m.log_time,
        };
        w.write_to_known_channel(&header, &m.data).unwrap();
        written += m.data.len() + 31;
    }
    written
}
