//! The scale-out deploy files (issue 17, part 5: `deploy/scale/compose.yaml`,
//! `deploy/k8s/scale/`) checked against the code by plain text scanning (no YAML parser among
//! the dependencies): every `RETEX_*` variable and every `retex serve` flag they use exists, the
//! HPA scales on a gauge that `/metrics` exports, each grace period outlasts the shutdown
//! deadline it covers, compose has its services with their roles, and the shared `retex.toml`
//! loads with the real loader and fits the worker pod's jobs into its memory limit.

use std::collections::BTreeSet;
use std::path::Path;

use retex::service::config::ServeConfig;

/// A file of the repository, by its path from the root.
macro_rules! repo {
    ($rel:literal) => {
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/", $rel)).expect($rel)
    };
}

/// The files of a folder of the repository with the extension `ext`, with their paths.
fn folder(rel: &str, ext: &str) -> Vec<(String, String)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    let mut out: Vec<(String, String)> = std::fs::read_dir(&dir)
        .expect(rel)
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == ext))
        .map(|p| (p.display().to_string(), std::fs::read_to_string(p).unwrap()))
        .collect();
    out.sort();
    out
}

fn k8s_files() -> Vec<(String, String)> {
    let files = folder("deploy/k8s/scale", "yaml");
    assert!(files.len() >= 6, "{} k8s files", files.len());
    files
}

/// Every `RETEX_NAME` in `text`.
fn retex_names(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (i, _) in text.match_indices("RETEX_") {
        let tail = &text[i + 6..];
        let is_name = |c: char| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_';
        let n = tail.find(|c: char| !is_name(c)).unwrap_or(tail.len());
        if n > 0 {
            out.insert(format!("RETEX_{}", &tail[..n]));
        }
    }
    out
}

/// The first whole number after `key` in `text`.
fn number_after(text: &str, key: &str) -> u64 {
    let at = text.find(key).expect(key) + key.len();
    let digits: String = text[at..]
        .chars()
        .skip_while(|c| !c.is_ascii_digit())
        .take_while(char::is_ascii_digit)
        .collect();
    digits.parse().expect(key)
}

/// The first line of `text` that contains every one of `parts`.
fn line_with<'a>(text: &'a str, parts: &[&str]) -> &'a str {
    let found = text.lines().find(|l| parts.iter().all(|p| l.contains(p)));
    found.unwrap_or_else(|| panic!("no line with {parts:?}"))
}

/// The value of the env entry `{name: NAME, value: "N"}` of a k8s manifest.
fn env_value(manifest: &str, name: &str) -> u64 {
    let entry = format!("name: {name},");
    number_after(line_with(manifest, &[entry.as_str(), "value:"]), "value:")
}

/// The lines of a compose service after `  name:`, up to the next line indented 2 or less.
fn service_block(compose: &str, name: &str) -> String {
    let head = format!("  {name}:");
    let mut lines = compose.lines().skip_while(|l| *l != head);
    assert!(lines.next().is_some(), "no service {name}");
    lines
        .take_while(|l| l.trim().is_empty() || l.starts_with("   "))
        .map(|l| format!("{l}\n"))
        .collect()
}

#[test]
fn every_retex_variable_is_read_by_the_code() {
    let mut code = repo!("src/service/config.rs");
    for (_, text) in folder("src/cli", "rs") {
        code.push_str(&text);
    }
    let mut files = k8s_files();
    files.push(("compose".into(), repo!("deploy/scale/compose.yaml")));
    let mut seen = 0;
    for (name, text) in &files {
        for var in retex_names(text) {
            assert!(code.contains(&format!("\"{var}\"")), "{name}: {var} unread");
            seen += 1;
        }
    }
    assert!(seen >= 10, "only {seen} RETEX_ names: scan broken?");
}

#[test]
fn every_serve_flag_is_a_flag_of_retex_serve() {
    let serve = repo!("src/cli/serve.rs");
    let mut texts = vec![repo!("deploy/scale/compose.yaml")];
    texts.extend(k8s_files().into_iter().map(|(_, text)| text));
    let mut flags = 0;
    for line in texts.iter().flat_map(|t| t.lines()) {
        let items: Vec<&str> = line.split('"').skip(1).step_by(2).collect();
        let command = line.contains("command:") || line.contains("args:");
        if !command || items.first() != Some(&"serve") {
            continue;
        }
        for flag in items.iter().filter_map(|i| i.strip_prefix("--")) {
            let field = flag.replace('-', "_");
            assert!(serve.contains(&format!("pub {field}:")), "--{flag}");
            flags += 1;
        }
    }
    assert!(flags >= 4, "only {flags} flags in serve commands");
}

#[test]
fn the_hpa_scales_on_an_exported_gauge() {
    let hpa = repo!("deploy/k8s/scale/hpa.yaml");
    let metric = &hpa[hpa.find("metric:").expect("an External metric")..];
    let name = line_with(metric, &["name:"]).split(':').nth(1).unwrap();
    let name = name.trim();
    assert_eq!(name, "retex_queue_depth");
    let metrics = repo!("src/service/http/metrics.rs");
    assert!(metrics.contains(&format!("# TYPE {name} gauge")), "{name}");
    let rules = repo!("deploy/k8s/scale/prometheus-adapter-rules.yaml");
    assert!(rules.contains(&format!("as: \"{name}\"")) && rules.contains("max by"));
    // The HPA's target per pod is one pod's job slots.
    let worker = repo!("deploy/k8s/scale/worker.yaml");
    let slots = env_value(&worker, "RETEX_WORKERS");
    assert_eq!(number_after(&hpa, "averageValue:"), slots);
}

#[test]
fn grace_periods_outlast_the_shutdown_deadlines() {
    for text in [
        repo!("deploy/k8s/scale/worker.yaml"),
        repo!("deploy/k8s/scale/api.yaml"),
    ] {
        let grace = number_after(&text, "terminationGracePeriodSeconds:");
        let secs = env_value(&text, "RETEX_SHUTDOWN_SECS");
        assert!(grace > secs + 5, "grace {grace} s, shutdown {secs} s");
    }
    let compose = repo!("deploy/scale/compose.yaml");
    for service in ["retex-api", "retex-worker"] {
        let block = service_block(&compose, service);
        let grace = number_after(&block, "stop_grace_period:");
        let secs = number_after(&block, "RETEX_SHUTDOWN_SECS:");
        assert!(grace > secs, "{service}: {grace} s <= {secs} s");
    }
}

#[test]
fn compose_and_k8s_set_the_roles() {
    let compose = repo!("deploy/scale/compose.yaml");
    for service in ["postgres", "minio", "minio-init"] {
        assert!(service_block(&compose, service).contains("image:"));
    }
    let api = service_block(&compose, "retex-api");
    assert!(api.contains(r#""--role", "api""#) && api.contains("8080:8080"));
    let worker = service_block(&compose, "retex-worker");
    assert!(worker.contains(r#""--role", "worker""#) && worker.contains("replicas: 2"));
    assert!(
        !worker.contains("ports:"),
        "replicas cannot share a host port"
    );
    let api = repo!("deploy/k8s/scale/api.yaml");
    assert!(api.contains("{name: RETEX_ROLE, value: api}"));
    let worker = repo!("deploy/k8s/scale/worker.yaml");
    assert!(worker.contains("{name: RETEX_ROLE, value: worker}"));
}

#[test]
fn the_shared_limits_fit_the_worker_pod() {
    let map = repo!("deploy/k8s/scale/configmap.yaml");
    let head = "retex.toml: |\n";
    let at = map.find(head).expect("retex.toml in configmap.yaml") + head.len();
    let toml: String = map[at..]
        .lines()
        .take_while(|l| l.starts_with("    ") || l.trim().is_empty())
        .map(|l| format!("{}\n", l.get(4..).unwrap_or("")))
        .collect();
    let mut c = ServeConfig::from_toml(&toml, Path::new("configmap.yaml")).unwrap();
    let worker = repo!("deploy/k8s/scale/worker.yaml");
    let slots = env_value(&worker, "RETEX_WORKERS") as usize;
    c.workers = slots;
    let notes = c.fit_workers().unwrap();
    assert!(notes.is_empty() && c.workers == slots, "{notes:?}");
    // deploy/README.md "Sizing": 3.5 GiB a job; the pod's limit holds the jobs and 512 MiB.
    let job = c.job_memory_bytes();
    assert!(job <= 7 << 29, "{job} bytes per job");
    let limit = number_after(line_with(&worker, &["limits:", "memory:"]), "memory:");
    assert!(
        c.memory_bytes.unwrap() + (512 << 20) <= limit << 30,
        "{limit} Gi"
    );
}
