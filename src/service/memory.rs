//! The memory the machine gives `retex serve` (issue 9, item 1): the default job budget
//! ([`crate::service::config::ServeConfig::memory_bytes`]) when neither the config nor
//! `RETEX_MEMORY_BYTES` sets one.
//!
//! The limit is the smallest of:
//! - the cgroup v2 `memory.max` of the process's cgroup and of each of its ancestors
//!   (`/proc/self/cgroup` line `0::<path>`, files `/sys/fs/cgroup<path>/memory.max`; `max` means
//!   no limit);
//! - the cgroup v1 `memory.limit_in_bytes` of the process's memory cgroup and its ancestors
//!   (line `<n>:...memory...:<path>`, files `/sys/fs/cgroup/memory<path>/memory.limit_in_bytes`;
//!   v1 writes "no limit" as a huge number near 2^63, so anything at or above
//!   [`UNLIMITED_FROM`] is no limit);
//! - `MemTotal` of `/proc/meminfo` (a cgroup limit above the machine's memory does not make
//!   more memory).
//!
//! The jobs get that less [`SERVER_RESERVE_BYTES`] for the server itself. Every function here
//! reads files through a closure, so the parsing is tested on strings.

/// Memory kept for the server besides its jobs: the HTTP side, SQLite's caches and the
/// connection buffers. Not a paper constant: the soak test measured the server process at
/// about 100 MB resident without jobs; 512 MiB leaves room for `max_connections` (512) buffers
/// of 64 KiB (32 MiB), the tokio and rayon threads' stacks and the page cache the upload spool
/// needs to keep moving.
pub const SERVER_RESERVE_BYTES: u64 = 512 << 20;

/// cgroup v1 limits at or above this are "no limit" (the kernel writes `PAGE_COUNTER_MAX`
/// × page size, 9223372036854771712 on x86-64).
pub const UNLIMITED_FROM: u64 = 1 << 60;

/// Where the machine's memory limit came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MachineMemory {
    /// The limit in bytes.
    pub bytes: u64,
    /// The file it was read from (for the start-up log).
    pub source: String,
}

impl MachineMemory {
    /// The budget of the jobs: the limit less [`SERVER_RESERVE_BYTES`] (at least 1 byte, so a
    /// tiny machine yields a budget that fits nothing and is refused with a clear message
    /// rather than meaning "no cap").
    pub fn job_budget(&self) -> u64 {
        self.bytes.saturating_sub(SERVER_RESERVE_BYTES).max(1)
    }
}

/// Parses a cgroup v2 `memory.max`: bytes, or `None` for `max` (no limit) and anything else.
pub fn parse_cgroup_v2_max(text: &str) -> Option<u64> {
    let t = text.trim();
    if t == "max" {
        return None;
    }
    t.parse().ok()
}

/// Parses a cgroup v1 `memory.limit_in_bytes`: bytes, or `None` for "no limit" (a value at or
/// above [`UNLIMITED_FROM`]) and anything unreadable.
pub fn parse_cgroup_v1_limit(text: &str) -> Option<u64> {
    text.trim()
        .parse()
        .ok()
        .filter(|&v: &u64| v < UNLIMITED_FROM)
}

/// `MemTotal` of a `/proc/meminfo` text, in bytes.
pub fn parse_meminfo_total(text: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let mut words = line["MemTotal:".len()..].split_whitespace();
    let value: u64 = words.next()?.parse().ok()?;
    let scale = match words.next() {
        Some("kB") | Some("KB") | Some("kb") => 1024,
        None => 1,
        Some(_) => return None,
    };
    value.checked_mul(scale)
}

/// The cgroup paths of a `/proc/self/cgroup` text: the v2 path (line `0::<path>`) and the v1
/// memory controller's path (a line whose controller list names `memory`).
pub fn parse_proc_cgroup(text: &str) -> (Option<String>, Option<String>) {
    let mut v2 = None;
    let mut v1 = None;
    for line in text.lines() {
        let mut fields = line.splitn(3, ':');
        let (Some(id), Some(controllers), Some(path)) =
            (fields.next(), fields.next(), fields.next())
        else {
            continue;
        };
        if id == "0" && controllers.is_empty() {
            v2 = Some(path.to_string());
        } else if controllers.split(',').any(|c| c == "memory") {
            v1 = Some(path.to_string());
        }
    }
    (v2, v1)
}

/// `path` and each of its ancestors, deepest first, ending with the root (`""`).
fn ancestors(path: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = path.trim_end_matches('/').to_string();
    loop {
        out.push(cur.clone());
        match cur.rfind('/') {
            Some(i) => cur.truncate(i),
            None => break,
        }
        if cur.is_empty() {
            out.push(String::new());
            break;
        }
    }
    out.dedup();
    out
}

/// The smallest limit over a cgroup and its ancestors: `file(dir)` names the limit file of a
/// cgroup folder, `parse` reads it.
fn cgroup_limit(
    path: &str,
    file: impl Fn(&str) -> String,
    parse: fn(&str) -> Option<u64>,
    read: &impl Fn(&str) -> Option<String>,
) -> Option<MachineMemory> {
    ancestors(path)
        .iter()
        .filter_map(|dir| {
            let name = file(dir);
            let bytes = parse(&read(&name)?)?;
            Some(MachineMemory {
                bytes,
                source: name,
            })
        })
        .min_by_key(|m| m.bytes)
}

/// The memory this process may use: the smallest of its cgroup limits (v2 and v1) and
/// `MemTotal`; `None` when none can be read. `read` returns a file's text (`None` if it cannot
/// be read).
pub fn detect(read: impl Fn(&str) -> Option<String>) -> Option<MachineMemory> {
    let (v2, v1) = read("/proc/self/cgroup")
        .map(|t| parse_proc_cgroup(&t))
        .unwrap_or_default();
    let mut found = Vec::new();
    found.extend(cgroup_limit(
        v2.as_deref().unwrap_or("/"),
        |d| format!("/sys/fs/cgroup{d}/memory.max"),
        parse_cgroup_v2_max,
        &read,
    ));
    found.extend(cgroup_limit(
        v1.as_deref().unwrap_or("/"),
        |d| format!("/sys/fs/cgroup/memory{d}/memory.limit_in_bytes"),
        parse_cgroup_v1_limit,
        &read,
    ));
    found.extend(
        read("/proc/meminfo")
            .and_then(|t| parse_meminfo_total(&t))
            .map(|bytes| MachineMemory {
                bytes,
                source: "/proc/meminfo MemTotal".into(),
            }),
    );
    found.into_iter().min_by_key(|m| m.bytes)
}

/// [`detect`] on this machine's files.
pub fn detect_here() -> Option<MachineMemory> {
    detect(|path| std::fs::read_to_string(path).ok())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[test]
    fn parses_the_three_sources() {
        assert_eq!(parse_cgroup_v2_max("max\n"), None);
        assert_eq!(parse_cgroup_v2_max("8589934592\n"), Some(8 << 30));
        assert_eq!(parse_cgroup_v2_max("lots"), None);
        assert_eq!(parse_cgroup_v1_limit("9223372036854771712\n"), None);
        assert_eq!(parse_cgroup_v1_limit("4294967296"), Some(4 << 30));
        let meminfo = "MemTotal:       24683652 kB\nMemFree:        16812252 kB\n";
        assert_eq!(parse_meminfo_total(meminfo), Some(24683652 * 1024));
        assert_eq!(parse_meminfo_total("MemFree: 1 kB\n"), None);
        assert_eq!(parse_meminfo_total("MemTotal: 12 MB\n"), None);
    }

    #[test]
    fn reads_the_cgroup_paths() {
        let text = "12:cpu,cpuacct:/a\n4:memory:/process_api/16aec\n0::/system.slice/x.service\n";
        assert_eq!(
            parse_proc_cgroup(text),
            (
                Some("/system.slice/x.service".into()),
                Some("/process_api/16aec".into())
            )
        );
        assert_eq!(ancestors("/a/b"), ["/a/b", "/a", ""]);
        assert_eq!(ancestors("/"), [""]);
    }

    fn machine(files: &[(&str, &str)]) -> Option<MachineMemory> {
        let map: HashMap<String, String> = files
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        detect(|p| map.get(p).cloned())
    }

    #[test]
    fn the_smallest_limit_wins() {
        let meminfo = ("/proc/meminfo", "MemTotal: 16777216 kB\n");
        // Bare metal: MemTotal.
        let m = machine(&[meminfo, ("/proc/self/cgroup", "0::/\n")]).unwrap();
        assert_eq!(m.bytes, 16 << 30);
        assert_eq!(m.job_budget(), (16 << 30) - SERVER_RESERVE_BYTES);
        // A v2 service with a limit on its parent slice; the root says max.
        let m = machine(&[
            meminfo,
            ("/proc/self/cgroup", "0::/system.slice/retex.service\n"),
            (
                "/sys/fs/cgroup/system.slice/retex.service/memory.max",
                "max\n",
            ),
            ("/sys/fs/cgroup/system.slice/memory.max", "4294967296\n"),
        ])
        .unwrap();
        assert_eq!(m.bytes, 4 << 30);
        assert_eq!(m.source, "/sys/fs/cgroup/system.slice/memory.max");
        // A container (namespaced v2): the root file is the container's.
        let m = machine(&[
            meminfo,
            ("/proc/self/cgroup", "0::/\n"),
            ("/sys/fs/cgroup/memory.max", "2147483648\n"),
        ])
        .unwrap();
        assert_eq!(m.bytes, 2 << 30);
        // v1: unlimited at the root, 3 GiB on the process's group.
        let m = machine(&[
            meminfo,
            ("/proc/self/cgroup", "4:memory:/docker/abc\n0::/\n"),
            (
                "/sys/fs/cgroup/memory/memory.limit_in_bytes",
                "9223372036854771712",
            ),
            (
                "/sys/fs/cgroup/memory/docker/abc/memory.limit_in_bytes",
                "3221225472",
            ),
        ])
        .unwrap();
        assert_eq!(m.bytes, 3 << 30);
        // A cgroup limit above the machine's memory: MemTotal.
        let m = machine(&[
            meminfo,
            ("/proc/self/cgroup", "0::/\n"),
            ("/sys/fs/cgroup/memory.max", "68719476736\n"),
        ])
        .unwrap();
        assert_eq!(m.bytes, 16 << 30);
        assert_eq!(machine(&[]), None);
        // Less than the reserve: a budget of 1 byte (fits nothing), never "no cap".
        let tiny = MachineMemory {
            bytes: 1 << 20,
            source: String::new(),
        };
        assert_eq!(tiny.job_budget(), 1);
    }
}
